//! The composed picture of a simulation state, for the demo's stills, the
//! watch pictures and animations alike: the surface coloured by a length in
//! mm on the tissue map, the spatulas as plates (blue-grey while touching
//! tissue), their reaction forces as arrows with readouts, a title band and a
//! colour scale.
//!
//! Layout (px): a title band at the top ([`TITLE_BAND`]), the 3-D view below
//! it on the left (drawn by [`super::raster`]), a legend panel ([`PANEL`]) on
//! the right whose colour scale is a `plotters` axis. Lengths in the scene
//! are metres; the scale and readouts show millimetres and newtons.

use super::plot::chart::{FONT, chart_err, draw_over, linear_label, rgb};
use super::raster::{
    Background, Camera, Colouring, EdgeStyle, MeshRef, RenderOptions, Renderer, Shading, TriMesh,
};
use super::text::{HAlign, TextStyle, VAlign, draw_text};
use super::{Image, RenderError, Rgb};
use nalgebra::{Isometry3, Point3, Vector3};
use plotters::prelude::*;

/// Height of the title band, px.
pub const TITLE_BAND: u32 = 58;
/// Width of the legend panel, px.
pub const PANEL: u32 = 120;

/// The tissue colour map: light pink at 0, salmon, orange-red, dark crimson
/// at 1 (sRGB stops, linear blend between them), so that tissue reads as
/// tissue and the deformation stands out.
pub const TISSUE_MAP: [(f64, Rgb); 4] = [
    (0.0, [240, 208, 200]),
    (0.35, [236, 150, 120]),
    (0.7, [214, 72, 52]),
    (1.0, [140, 16, 40]),
];

/// The colour of `t` in [0, 1] on [`TISSUE_MAP`] (clamped; NaN gives grey).
pub fn tissue_colour(t: f64) -> Rgb {
    if t.is_nan() {
        return [160, 160, 160];
    }
    let t = t.clamp(0.0, 1.0);
    for w in TISSUE_MAP.windows(2) {
        let ((t0, a), (t1, b)) = (w[0], w[1]);
        if t <= t1 {
            let u = (t - t0) / (t1 - t0);
            return [0, 1, 2]
                .map(|c| (a[c] as f64 + (b[c] as f64 - a[c] as f64) * u).round() as u8);
        }
    }
    TISSUE_MAP[TISSUE_MAP.len() - 1].1
}

/// Plate colour.
pub const STEEL: Rgb = [150, 160, 176];
/// Plate colour while it touches tissue.
pub const STEEL_CONTACT: Rgb = [95, 130, 190];
/// A blade's cutting edge.
pub const CUTTING_EDGE: Rgb = [235, 150, 20];
/// Force arrows, per instrument.
pub const ARROWS: [Rgb; 2] = [[20, 90, 220], [20, 150, 90]];

/// A camera placement: azimuth and elevation (degrees) and the box framed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraPreset {
    /// Azimuth about +z from +x, degrees (the eye's direction from the box).
    pub azimuth_deg: f64,
    /// Elevation above the xy plane, degrees.
    pub elevation_deg: f64,
    /// Box framed, m.
    pub frame_box: (Point3<f64>, Point3<f64>),
}

/// What to write on a picture.
#[derive(Debug, Clone, PartialEq)]
pub struct Caption {
    /// Title (bold, top-left).
    pub title: String,
    /// Second line.
    pub subtitle: String,
    /// Value at the top of the colour scale, mm (> 0).
    pub range_mm: f64,
    /// Arrow length per newton, m/N; `None`: the largest force of the frame
    /// is drawn 30 % of the framed box's diagonal long.
    pub force_scale: Option<f64>,
}

/// A closed triangle surface: vertex positions (m) and outward triangles.
pub type Outline = (Vec<Point3<f64>>, Vec<[u32; 3]>);

/// A spatula to draw: a plate with its reaction force.
#[derive(Debug, Clone, PartialEq)]
pub struct Plate {
    /// Name shown with the force readout and at the arrow's tip.
    pub name: String,
    /// Pose of the plate's centre (local to world), m.
    pub pose: Isometry3<f64>,
    /// Half-extents along the local axes (half thickness, width, length), m:
    /// the box drawn when there is no [`Plate::outline`].
    pub half_extents: Vector3<f64>,
    /// The plate's true surface, posed (m, outward triangles): a curved
    /// plate bent, a trapezoid tapered. `None`: the box.
    pub outline: Option<Outline>,
    /// A blade's cutting edge, posed (m), drawn as an amber rod over the
    /// tissue and the plate (it is inside the fissure when it cuts).
    pub cutting_edge: Option<[Point3<f64>; 2]>,
    /// Reaction force on the spatula, N (drawn from the plate's centre).
    pub force: Option<Vector3<f64>>,
    /// Whether it touches tissue.
    pub touching: bool,
}

/// One state to draw.
#[derive(Debug, Clone, Copy)]
pub struct Scene<'a> {
    /// Surface vertex positions, m.
    pub positions: &'a [Point3<f64>],
    /// Surface triangles.
    pub triangles: &'a [[u32; 3]],
    /// Per-vertex value shown by the colour, mm (0 at the light end of the
    /// scale, [`Caption::range_mm`] at the dark end).
    pub values_mm: &'a [f64],
    /// What the values are, written above the scale, e.g. "displacement".
    pub quantity: &'a str,
    /// Their unit, written under the quantity, e.g. "(mm)".
    pub unit: &'a str,
    /// The spatulas.
    pub plates: &'a [Plate],
    /// The ties across the fissure that hold.
    pub ties: &'a [TieSegment],
    /// The camera.
    pub camera: CameraPreset,
}

/// A tie to draw: its ends, m, and whether it is a vessel (else a
/// trabecula).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TieSegment {
    /// One end, m.
    pub a: Point3<f64>,
    /// The other end, m.
    pub b: Point3<f64>,
    /// A bridging vessel (drawn thicker, in red).
    pub vessel: bool,
}

/// Trabeculae: pale, thin; vessels: red, thicker.
const TRABECULA: Rgb = [236, 226, 190];
const VESSEL: Rgb = [178, 34, 40];

/// The ties as thin square rods (radius `r` m for a trabecula, 3 r for a
/// vessel), one mesh.
fn tie_rods(ties: &[TieSegment], r: f64) -> Vec<TriMesh> {
    let mut out: Vec<TriMesh> = Vec::new();
    for vessel in [false, true] {
        let mut all: Option<TriMesh> = None;
        let (w, colour) = if vessel {
            (3.0 * r, VESSEL)
        } else {
            (r, TRABECULA)
        };
        for t in ties.iter().filter(|t| t.vessel == vessel) {
            let Some(rod) = rod(t.a, t.b, w, colour) else {
                continue;
            };
            match &mut all {
                Some(m) => m.append(&rod),
                None => all = Some(rod),
            }
        }
        out.extend(all);
    }
    out
}

/// A square rod of half-width `w` from `a` to `b` (m); `None` when the two
/// coincide or are not finite.
fn rod(a: Point3<f64>, b: Point3<f64>, w: f64, colour: Rgb) -> Option<TriMesh> {
    let d = b - a;
    let len = d.norm();
    if !(len > 0.0 && len.is_finite()) {
        return None;
    }
    let rotation =
        nalgebra::UnitQuaternion::rotation_between(&Vector3::z(), &d).unwrap_or_else(|| {
            nalgebra::UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
        });
    let pose = Isometry3::from_parts(nalgebra::center(&a, &b).coords.into(), rotation);
    Some(TriMesh::cuboid(
        &pose,
        Vector3::new(w, w, 0.5 * len),
        colour,
    ))
}

/// Draws [`Scene`]s at one size, keeping the rasteriser's buffers between
/// frames.
pub struct FrameRenderer {
    width: u32,
    height: u32,
    renderer: Renderer,
    background: Background,
    colours: Vec<Rgb>,
}

impl FrameRenderer {
    /// A renderer of `width` x `height` px pictures (at least 320 x 240).
    pub fn new(width: u32, height: u32) -> Result<Self, RenderError> {
        if width < 320 || height < 240 {
            return Err(RenderError::BadSize { width, height });
        }
        let background = Background::Gradient {
            top: [250, 251, 253],
            bottom: [205, 212, 222],
        };
        let opts = RenderOptions {
            background: Background::Gradient {
                top: background.at(TITLE_BAND as usize, height),
                bottom: background.at(height as usize - 1, height),
            },
            ..RenderOptions::new(width - PANEL, height - TITLE_BAND)
        };
        Ok(Self {
            width,
            height,
            renderer: Renderer::new(opts)?,
            background,
            colours: Vec::new(),
        })
    }

    /// Draws `scene`: the surface coloured by its values, the plates, force
    /// arrows and readouts, the caption and the colour scale.
    pub fn render(&mut self, scene: &Scene<'_>, caption: &Caption) -> Result<Image, RenderError> {
        if scene.values_mm.len() != scene.positions.len() {
            return Err(RenderError::LengthMismatch {
                mesh: 0,
                what: "values",
                got: scene.values_mm.len(),
                vertices: scene.positions.len(),
            });
        }
        let range = if caption.range_mm.is_finite() && caption.range_mm > 0.0 {
            caption.range_mm
        } else {
            1.0
        };
        self.colours.clear();
        self.colours
            .extend(scene.values_mm.iter().map(|v| tissue_colour(v / range)));
        let plates: Vec<TriMesh> = scene
            .plates
            .iter()
            .map(|p| {
                let c = if p.touching { STEEL_CONTACT } else { STEEL };
                match &p.outline {
                    Some((positions, triangles)) => TriMesh {
                        positions: positions.clone(),
                        triangles: triangles.clone(),
                        colour: c,
                        shading: Shading::Flat,
                        specular: 0.5,
                    },
                    None => TriMesh::cuboid(&p.pose, p.half_extents, c),
                }
            })
            .collect();
        let (lo, hi) = scene.camera.frame_box;
        let aspect = self.renderer.options().aspect();
        let cam = Camera::orbit_box(
            lo,
            hi,
            scene.camera.azimuth_deg,
            scene.camera.elevation_deg,
            30.0,
            aspect,
        );
        let diag = (hi - lo).norm();
        let fmax = scene
            .plates
            .iter()
            .filter_map(|p| p.force)
            .map(|f| f.norm())
            .filter(|f| f.is_finite())
            .fold(0.0, f64::max);
        let scale = caption
            .force_scale
            .unwrap_or(if fmax > 0.0 { 0.3 * diag / fmax } else { 0.0 });
        let arrows: Vec<(usize, TriMesh)> = scene
            .plates
            .iter()
            .enumerate()
            .filter_map(|(i, p)| {
                let a = TriMesh::arrow(
                    p.pose.translation.vector.into(),
                    p.force? * scale,
                    0.008 * diag,
                    ARROWS[i % 2],
                );
                (!a.triangles.is_empty()).then_some((i, a))
            })
            .collect();
        let mut surface = MeshRef::new(
            scene.positions,
            scene.triangles,
            Colouring::PerVertex(&self.colours),
        )
        .with_specular(0.06);
        // Edges help read coarse meshes and only darken fine ones.
        if scene.triangles.len() < 4000 {
            surface = surface.with_edges(EdgeStyle {
                colour: [90, 40, 40],
                width: 0.35,
                opacity: 0.18,
            });
        }
        let rods = tie_rods(scene.ties, 0.0015 * diag);
        let edges: Vec<TriMesh> = scene
            .plates
            .iter()
            .filter_map(|p| p.cutting_edge)
            .filter_map(|[a, b]| rod(a, b, 0.002 * diag, CUTTING_EDGE))
            .collect();
        let mut meshes = vec![surface];
        meshes.extend(plates.iter().map(TriMesh::as_mesh));
        meshes.extend(rods.iter().map(TriMesh::as_mesh));
        // Over everything: the edge is inside the fissure when it cuts.
        meshes.extend(edges.iter().map(|e| e.as_mesh().on_top()));
        meshes.extend(arrows.iter().map(|(_, a)| a.as_mesh().on_top()));
        let picture = self.renderer.render(&cam, &meshes)?;

        let mut img = Image::new(self.width, self.height, [0; 3])?;
        for y in 0..self.height as usize {
            let c = self.background.at(y, self.height);
            img.pixels_mut()[y * self.width as usize..(y + 1) * self.width as usize].fill(c);
        }
        img.blit(&picture, 0, TITLE_BAND as i64);
        let ink = [25, 28, 35];
        draw_text(
            &mut img,
            &caption.title,
            18.0,
            12.0,
            &TextStyle::new(19.0).bold().colour(ink),
        );
        draw_text(
            &mut img,
            &caption.subtitle,
            18.0,
            37.0,
            &TextStyle::new(13.0).colour([80, 84, 92]),
        );
        colour_scale(
            &mut img,
            (self.width - PANEL) as i32 + 16,
            TITLE_BAND as i32 + 34,
            ((self.height - TITLE_BAND) as i32 - 120).clamp(80, 360),
            range,
            scene.quantity,
            scene.unit,
        )?;
        // Force readouts bottom-left, names at the arrow tips.
        let st = TextStyle::new(14.0).align(HAlign::Left, VAlign::Bottom);
        let mut y = self.height as f32 - 12.0;
        for (i, p) in scene.plates.iter().enumerate().rev() {
            if let Some(f) = p.force {
                let text = format!(
                    "{}: |F| = {:.3} N   ({:+.3}, {:+.3}, {:+.3}) N{}",
                    p.name,
                    f.norm(),
                    f.x,
                    f.y,
                    f.z,
                    if p.touching { "" } else { "   no contact" }
                )
                .replace('-', "\u{2212}");
                draw_text(&mut img, &text, 18.0, y, &st.colour(ARROWS[i % 2]));
                y -= 20.0;
            }
        }
        let size = (picture.width(), picture.height());
        for (i, a) in &arrows {
            let p = &scene.plates[*i];
            let Some(f) = p.force else { continue };
            let base = Point3::from(p.pose.translation.vector);
            label_arrow(
                &mut img,
                &cam,
                size,
                &base,
                &(base + f * scale),
                &p.name,
                a.colour,
            );
        }
        Ok(img)
    }
}

/// Writes `name` 14 px beyond the tip of the arrow `base -> tip` (m) as seen
/// through `cam` in a view of `size` px drawn below the title band, aligned
/// so that the text never covers the arrow. Nothing when either end is
/// behind the camera.
fn label_arrow(
    img: &mut Image,
    cam: &Camera,
    size: (u32, u32),
    base: &Point3<f64>,
    tip: &Point3<f64>,
    name: &str,
    colour: Rgb,
) {
    let (Some(p0), Some(p1)) = (
        cam.project(base, size.0, size.1),
        cam.project(tip, size.0, size.1),
    ) else {
        return;
    };
    let (dx, dy) = (p1[0] - p0[0], p1[1] - p0[1]);
    let len = dx.hypot(dy).max(1e-9);
    let (ux, uy) = (dx / len, dy / len);
    let h = if ux < -0.3 {
        HAlign::Right
    } else if ux > 0.3 {
        HAlign::Left
    } else {
        HAlign::Center
    };
    let v = if uy < -0.3 {
        VAlign::Bottom
    } else if uy > 0.3 {
        VAlign::Top
    } else {
        VAlign::Middle
    };
    let lbl = TextStyle::new(13.0).bold().colour(colour).align(h, v);
    let gap = 14.0;
    let (x, y) = (p1[0] + gap * ux, p1[1] + gap * uy + TITLE_BAND as f64);
    draw_text(img, name, x as f32, y as f32, &lbl);
}

/// Width of the colour scale's bar, px.
const BAR_W: i32 = 18;

/// The colour scale: [`TISSUE_MAP`] from 0 (bottom) to `range_mm` (top) in
/// a `bar_h` px bar whose top-left corner is (`x`, `y`), its ticks and labels
/// on a `plotters` axis right of it, `quantity` and its `unit` above.
fn colour_scale(
    img: &mut Image,
    x: i32,
    y: i32,
    bar_h: i32,
    range_mm: f64,
    quantity: &str,
    unit: &str,
) -> Result<(), RenderError> {
    let ink = RGBColor(40, 40, 40);
    let label_w = 60;
    draw_over(img, |root| {
        let area = root.clone().shrink((x, y), (BAR_W + label_w, bar_h));
        let mut ch = ChartBuilder::on(&area)
            .set_label_area_size(LabelAreaPosition::Right, label_w)
            .build_cartesian_2d(0.0..1.0, 0.0..range_mm)
            .map_err(chart_err)?;
        ch.draw_series((0..bar_h).map(|j| {
            let t0 = j as f64 / bar_h as f64;
            let t1 = (j + 1) as f64 / bar_h as f64;
            let c = rgb(tissue_colour(0.5 * (t0 + t1)));
            Rectangle::new([(0.0, t0 * range_mm), (1.0, t1 * range_mm)], c.filled())
        }))
        .map_err(chart_err)?;
        // About one labelled tick per 45 px (key points, not intervals).
        ch.configure_mesh()
            .disable_mesh()
            .disable_x_axis()
            .set_tick_mark_size(LabelAreaPosition::Right, 6)
            .y_labels((bar_h / 45).clamp(2, 8) as usize + 1)
            .y_label_formatter(&|v| linear_label(*v))
            .label_style((FONT, 13.0).into_font().color(&ink))
            .axis_style(RGBColor(90, 90, 90))
            .draw()
            .map_err(chart_err)?;
        let (xs, ys) = ch.plotting_area().get_pixel_range();
        root.draw(&Rectangle::new(
            [(xs.start, ys.start), (xs.end, ys.end)],
            RGBColor(90, 90, 90),
        ))
        .map_err(chart_err)
    })?;
    let st = TextStyle::new(13.0)
        .colour([40, 40, 40])
        .align(HAlign::Left, VAlign::Bottom);
    draw_text(img, quantity, (x - 6) as f32, (y - 22) as f32, &st);
    draw_text(img, unit, (x - 6) as f32, (y - 7) as f32, &st);
    Ok(())
}

/// Axis-aligned bounds of `positions` (a unit box at the origin when empty).
pub fn bounds(positions: &[Point3<f64>]) -> (Point3<f64>, Point3<f64>) {
    let mut lo = Point3::from(Vector3::repeat(f64::INFINITY));
    let mut hi = Point3::from(Vector3::repeat(f64::NEG_INFINITY));
    for p in positions
        .iter()
        .filter(|p| p.coords.iter().all(|c| c.is_finite()))
    {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    if lo.x > hi.x {
        (Point3::origin(), Point3::new(1.0, 1.0, 1.0))
    } else {
        (lo, hi)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tissue_map_is_light_at_rest_and_strong_at_the_top() {
        let lum = |c: Rgb| 0.2126 * c[0] as f64 + 0.7152 * c[1] as f64 + 0.0722 * c[2] as f64;
        let rest = tissue_colour(0.0);
        assert!(lum(rest) > 190.0, "{rest:?}");
        assert!(rest[0] > rest[1] && rest[0] > rest[2], "pinkish {rest:?}");
        // Luminance falls monotonically with displacement.
        let mut prev = f64::INFINITY;
        for k in 0..=20 {
            let l = lum(tissue_colour(k as f64 / 20.0));
            assert!(l <= prev + 1e-9, "{k}");
            prev = l;
        }
        assert!(lum(tissue_colour(1.0)) < 60.0);
        assert_eq!(tissue_colour(2.0), tissue_colour(1.0));
        assert_eq!(tissue_colour(f64::NAN), [160, 160, 160]);
    }

    #[test]
    fn colour_scale_runs_from_rest_colour_at_bottom_to_top_colour_at_top() {
        let mut img = Image::new(200, 300, [255; 3]).unwrap();
        colour_scale(&mut img, 20, 40, 200, 4.0, "displacement", "(mm)").unwrap();
        let near = |a: Rgb, b: Rgb| {
            a.iter()
                .zip(b)
                .all(|(x, y)| (*x as i32 - y as i32).abs() <= 8)
        };
        let top = img.get(29, 43).unwrap();
        let bottom = img.get(29, 236).unwrap();
        assert!(near(top, tissue_colour(1.0)), "top {top:?}");
        assert!(near(bottom, tissue_colour(0.0)), "bottom {bottom:?}");
        // Tick labels right of the bar put ink there.
        let ink = (40..120)
            .flat_map(|x| (40..240).map(move |y| (x, y)))
            .filter(|&(x, y)| img.get(x, y).unwrap()[0] < 200)
            .count();
        assert!(ink > 50, "{ink} dark pixels of labels");
    }

    /// A plate drawn from its outline shows the outline's form (a
    /// trapezoid: narrower at the base than the box of its tip width), and
    /// a blade's cutting edge is drawn in amber; without an edge there is
    /// no amber.
    #[test]
    fn a_plate_is_drawn_from_its_outline_with_its_cutting_edge() {
        // A trapezoid plate 1 x (4 to 12) x 40 mm along +z, seen from +x.
        let (h2, l) = (0.0005, 0.04);
        let mut positions = Vec::new();
        for (z, w2) in [(0.0, 0.002), (l, 0.006)] {
            for (y, x) in [(-w2, h2), (w2, h2), (w2, -h2), (-w2, -h2)] {
                positions.push(Point3::new(x, y, z));
            }
        }
        let mut triangles = Vec::new();
        for j in 0..4u32 {
            let (p, q) = (j, (j + 1) % 4);
            triangles.push([p, q, q + 4]);
            triangles.push([p, q + 4, p + 4]);
        }
        triangles.extend([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7]]);
        let plate = |edge: Option<[Point3<f64>; 2]>| Plate {
            name: "blade".into(),
            pose: Isometry3::translation(0.0, 0.0, 0.5 * l),
            half_extents: Vector3::new(h2, 0.006, 0.5 * l),
            outline: Some((positions.clone(), triangles.clone())),
            cutting_edge: edge,
            force: None,
            touching: false,
        };
        let edge = [Point3::new(0.0, -0.006, l), Point3::new(0.0, 0.006, l)];
        let draw = |p: Plate| {
            let mut r = FrameRenderer::new(320, 320).unwrap();
            let far = [
                Point3::new(-1.0, 0.0, 0.0),
                Point3::new(-1.0, 0.001, 0.0),
                Point3::new(-1.0, 0.0, 0.001),
            ];
            let scene = Scene {
                positions: &far,
                triangles: &[[0, 1, 2]],
                values_mm: &[0.0; 3],
                quantity: "displacement",
                unit: "(mm)",
                plates: std::slice::from_ref(&p),
                ties: &[],
                camera: CameraPreset {
                    azimuth_deg: 0.0,
                    elevation_deg: 0.0,
                    frame_box: (Point3::new(0.0, -0.01, 0.0), Point3::new(0.001, 0.01, l)),
                },
            };
            let cap = Caption {
                title: String::new(),
                subtitle: String::new(),
                range_mm: 1.0,
                force_scale: None,
            };
            r.render(&scene, &cap).unwrap()
        };
        // Amber pixels of `img` that `other` does not have (the colour
        // scale has orange of its own).
        let amber = |img: &Image, other: &Image| {
            let (w, h) = (img.width(), img.height());
            (0..w)
                .flat_map(|x| (0..h).map(move |y| (x, y)))
                .filter(|&(x, y)| {
                    let c = img.get(x, y).unwrap();
                    let [r, g, b] = c.map(f64::from);
                    c != other.get(x, y).unwrap()
                        && r > 100.0
                        && b < 0.35 * r
                        && g > 0.4 * r
                        && g < 0.8 * r
                })
                .count()
        };
        let steel = |img: &Image, row: u32| {
            (0..img.width())
                .filter(|&x| {
                    // Steel is blue-grey and darker than the background.
                    let [r, _, b] = img.get(x, row).unwrap();
                    b > r && b > 100 && r < 200
                })
                .count()
        };
        let with_edge = draw(plate(Some(edge)));
        let without = draw(plate(None));
        let drawn = amber(&with_edge, &without);
        assert!(drawn > 20, "{drawn} amber pixels");
        assert_eq!(amber(&without, &with_edge), 0);
        // Steel rows near the tip are wider than near the base (12 mm
        // against 4 mm across): the outline, not the box, was drawn.
        let rows: Vec<(u32, usize)> = (0..without.height())
            .map(|y| (y, steel(&without, y)))
            .filter(|&(_, n)| n > 0)
            .collect();
        let (first, last) = (rows.first().unwrap(), rows.last().unwrap());
        let (wide, narrow) = if first.1 > last.1 {
            (first.1, last.1)
        } else {
            (last.1, first.1)
        };
        assert!(wide as f64 > 2.0 * narrow as f64, "steel widths {rows:?}");
    }

    #[test]
    fn values_must_match_the_vertices() {
        let mut r = FrameRenderer::new(320, 240).unwrap();
        let scene = Scene {
            positions: &[Point3::origin(); 3],
            triangles: &[[0, 1, 2]],
            values_mm: &[0.0; 2],
            quantity: "displacement",
            unit: "(mm)",
            plates: &[],
            ties: &[],
            camera: CameraPreset {
                azimuth_deg: 0.0,
                elevation_deg: 30.0,
                frame_box: (Point3::origin(), Point3::new(1.0, 1.0, 1.0)),
            },
        };
        let cap = Caption {
            title: String::new(),
            subtitle: String::new(),
            range_mm: 1.0,
            force_scale: None,
        };
        assert!(matches!(
            r.render(&scene, &cap),
            Err(RenderError::LengthMismatch { got: 2, .. })
        ));
    }
}
