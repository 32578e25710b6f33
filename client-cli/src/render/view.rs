//! The composed picture of a simulation state: the brain surface coloured by
//! a quantity, the spatulas as plates, their reaction forces as arrows with
//! readouts, a title and a colour legend. One call per frame, for the demo's
//! stills and the watch animations.
//!
//! Layout (px): a title band at the top (`TITLE_BAND`), the 3-D view below it
//! on the left, a legend panel (`PANEL`) on the right. Lengths in the scene
//! are metres; the legend shows millimetres for heights and displacements.

use super::colormap::{Colormap, Legend, finite_range};
use super::raster::{
    Background, Camera, Colouring, EdgeStyle, MeshRef, RenderOptions, Renderer, TriMesh,
};
use super::text::{HAlign, TextStyle, VAlign, draw_text, measure};
use super::{Image, RenderError, Rgb};
use nalgebra::{Isometry3, Point3, Vector3};

/// Height of the title band, px.
pub const TITLE_BAND: u32 = 58;

/// Writes `name` just beyond the tip of the arrow `base -> tip` (m) as seen
/// through `cam` in a view of `size` px drawn below the title band of `img`,
/// `gap` px past the tip along the arrow's screen direction, aligned so the
/// text never covers the arrow. Nothing when either end is behind the camera.
pub fn label_arrow(
    img: &mut Image,
    cam: &Camera,
    size: (u32, u32),
    base: &Point3<f64>,
    tip: &Point3<f64>,
    name: &str,
    colour: Rgb,
    gap: f64,
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
    let (x, y) = (p1[0] + gap * ux, p1[1] + gap * uy + TITLE_BAND as f64);
    draw_text(img, name, x as f32, y as f32, &lbl);
}
/// Width of the legend panel, px.
pub const PANEL: u32 = 130;

/// A spatula to draw: a plate with its reaction force.
#[derive(Debug, Clone, PartialEq)]
pub struct SpatulaView {
    /// Name shown with the force readout, e.g. "left".
    pub name: String,
    /// Pose of the plate's centre (local to world), m.
    pub pose: Isometry3<f64>,
    /// Half-extents along the local axes (half thickness, width, length), m.
    pub half_extents: Vector3<f64>,
    /// Reaction force on the spatula, N (drawn from the plate's centre).
    pub force: Option<Vector3<f64>>,
}

/// What colours the surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SurfaceColour<'a> {
    /// Height z, shown in mm.
    Height,
    /// Displacement magnitude |x - rest|, shown in mm; `rest` has one
    /// position per surface vertex.
    Displacement {
        /// Rest positions, m.
        rest: &'a [Point3<f64>],
    },
    /// Any per-vertex scalar, already in display units.
    Scalar {
        /// Values, one per vertex.
        values: &'a [f64],
        /// Legend title, e.g. "stress (kPa)".
        title: &'a str,
        /// The map.
        map: Colormap,
    },
    /// Tissue colour only, no legend.
    Tissue,
}

/// How to draw one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewSpec<'a> {
    /// Title (bold, top-left).
    pub title: String,
    /// Second line under the title, e.g. "frame 12   t = 0.40 s".
    pub subtitle: String,
    /// Surface colouring.
    pub colour: SurfaceColour<'a>,
    /// Legend range in display units; from the data when `None` (give it for
    /// animations so that colours mean the same in every frame).
    pub range: Option<(f64, f64)>,
    /// Camera azimuth about +z from +x, degrees.
    pub azimuth_deg: f64,
    /// Camera elevation above the xy plane, degrees.
    pub elevation_deg: f64,
    /// Box to frame; the bounds of the surface and the plates when `None`
    /// (fix it for animations so that the camera does not move).
    pub frame_box: Option<(Point3<f64>, Point3<f64>)>,
    /// Arrow length per newton, m/N; when `None`, the largest force is drawn
    /// 35 % of the framed box's diagonal long.
    pub force_scale: Option<f64>,
    /// Draw the triangle edges faintly.
    pub edges: bool,
}

impl<'a> ViewSpec<'a> {
    /// A view from the front-left and above, coloured by height.
    pub fn new(title: impl Into<String>) -> Self {
        Self {
            title: title.into(),
            subtitle: String::new(),
            colour: SurfaceColour::Height,
            range: None,
            azimuth_deg: -60.0,
            elevation_deg: 35.0,
            frame_box: None,
            force_scale: None,
            edges: true,
            // Tissue-like default for colour-free views lives in TISSUE.
        }
    }
}

/// Surface colour of [`SurfaceColour::Tissue`].
pub const TISSUE: Rgb = [226, 170, 160];
/// Plate colour.
pub const STEEL: Rgb = [196, 203, 214];
/// Force arrows, per instrument.
pub const ARROWS: [Rgb; 2] = [[31, 87, 200], [220, 90, 20]];

/// Renders composed frames of one size, keeping buffers between frames.
pub struct ViewRenderer {
    width: u32,
    height: u32,
    renderer: Renderer,
    background: Background,
    values: Vec<f64>,
    points: Vec<Point3<f64>>,
}

impl ViewRenderer {
    /// A renderer for `width` x `height` px pictures (at least 320 x 240).
    pub fn new(width: u32, height: u32) -> Result<Self, RenderError> {
        if width < 320 || height < 240 {
            return Err(RenderError::BadSize { width, height });
        }
        let background = Background::default();
        let view_h = height - TITLE_BAND;
        let opts = RenderOptions {
            background: Background::Gradient {
                top: background.at(TITLE_BAND as usize, height),
                bottom: background.at(height as usize - 1, height),
            },
            ..RenderOptions::new(width - PANEL, view_h)
        };
        Ok(Self {
            width,
            height,
            renderer: Renderer::new(opts)?,
            background,
            values: Vec::new(),
            points: Vec::new(),
        })
    }

    /// Draws the surface (`positions`, `triangles`), the spatulas and their
    /// forces as described by `spec`.
    pub fn render(
        &mut self,
        positions: &[Point3<f64>],
        triangles: &[[u32; 3]],
        spatulas: &[SpatulaView],
        spec: &ViewSpec<'_>,
    ) -> Result<Image, RenderError> {
        let plates: Vec<TriMesh> = spatulas
            .iter()
            .map(|s| TriMesh::cuboid(&s.pose, s.half_extents, STEEL))
            .collect();
        let aspect = self.renderer.options().aspect();
        let (cam, (lo, hi)) = match spec.frame_box {
            Some((lo, hi)) => (
                Camera::orbit_box(lo, hi, spec.azimuth_deg, spec.elevation_deg, 30.0, aspect),
                (lo, hi),
            ),
            None => {
                let mut pts = std::mem::take(&mut self.points);
                pts.clear();
                pts.extend_from_slice(positions);
                pts.extend(plates.iter().flat_map(|m| m.positions.iter().copied()));
                let cam =
                    Camera::orbit_points(&pts, spec.azimuth_deg, spec.elevation_deg, 30.0, aspect);
                let b = bounds(&pts);
                self.points = pts;
                (cam, b)
            }
        };
        // Per-vertex values in display units and the legend.
        self.values.clear();
        let (legend_title, map) = match spec.colour {
            SurfaceColour::Height => {
                self.values.extend(positions.iter().map(|p| p.z * 1e3));
                ("height (mm)", Colormap::Viridis)
            }
            SurfaceColour::Displacement { rest } => {
                if rest.len() != positions.len() {
                    return Err(RenderError::LengthMismatch {
                        mesh: 0,
                        what: "rest positions",
                        got: rest.len(),
                        vertices: positions.len(),
                    });
                }
                self.values.extend(
                    positions
                        .iter()
                        .zip(rest)
                        .map(|(p, r)| (p - r).norm() * 1e3),
                );
                ("displacement (mm)", Colormap::Viridis)
            }
            SurfaceColour::Scalar { values, title, map } => {
                self.values.extend_from_slice(values);
                (title, map)
            }
            SurfaceColour::Tissue => ("", Colormap::Viridis),
        };
        let range = spec
            .range
            .or_else(|| finite_range(&self.values))
            .unwrap_or((0.0, 1.0));
        let range = if range.1 > range.0 {
            range
        } else {
            (range.0, range.0 + 1.0)
        };
        let colouring = match spec.colour {
            SurfaceColour::Tissue => Colouring::Uniform(TISSUE),
            _ => Colouring::Scalar {
                values: &self.values,
                map,
                range,
            },
        };
        let mut surface = MeshRef::new(positions, triangles, colouring).with_specular(0.08);
        if spec.edges {
            surface = surface.with_edges(EdgeStyle {
                colour: [15, 15, 25],
                width: 0.35,
                opacity: 0.22,
            });
        }
        let diag = (hi - lo).norm();
        let fmax = spatulas
            .iter()
            .filter_map(|s| s.force)
            .map(|f| f.norm())
            .filter(|f| f.is_finite())
            .fold(0.0, f64::max);
        let scale = spec
            .force_scale
            .unwrap_or(if fmax > 0.0 { 0.35 * diag / fmax } else { 0.0 });
        let arrows: Vec<(usize, TriMesh)> = spatulas
            .iter()
            .enumerate()
            .filter_map(|(i, s)| {
                let f = s.force?;
                let a = TriMesh::arrow(
                    s.pose.translation.vector.into(),
                    f * scale,
                    0.006 * diag,
                    ARROWS[i % 2],
                );
                (!a.triangles.is_empty()).then_some((i, a))
            })
            .collect();
        let mut meshes = vec![surface];
        meshes.extend(plates.iter().map(TriMesh::as_mesh));
        meshes.extend(arrows.iter().map(|(_, a)| a.as_mesh().on_top()));
        let view = self.renderer.render(&cam, &meshes)?;

        // Compose.
        let mut img = Image::new(self.width, self.height, [0; 3])?;
        for y in 0..self.height as usize {
            let c = self.background.at(y, self.height);
            img.pixels_mut()[y * self.width as usize..(y + 1) * self.width as usize].fill(c);
        }
        img.blit(&view, 0, TITLE_BAND as i64);
        let ink = [25, 28, 35];
        draw_text(
            &mut img,
            &spec.title,
            18.0,
            12.0,
            &TextStyle::new(19.0).bold().colour(ink),
        );
        if !spec.subtitle.is_empty() {
            draw_text(
                &mut img,
                &spec.subtitle,
                18.0,
                37.0,
                &TextStyle::new(13.0).colour([80, 84, 92]),
            );
        }
        if !legend_title.is_empty() {
            let legend = Legend::new(map, range, legend_title);
            let bar_h = ((self.height - TITLE_BAND) as i64 - 110).clamp(80, 360);
            let x = (self.width - PANEL) as i64 + 14;
            // Keep the title inside the picture.
            let tw = measure(legend_title, &TextStyle::new(legend.text_size)).width as i64;
            let x = x.min(self.width as i64 - tw - 6);
            legend.draw(&mut img, x, TITLE_BAND as i64 + 30, 18, bar_h);
        }
        // Force readouts, bottom-left, in the arrows' colours, and the
        // instrument names next to the arrow tips.
        let st = TextStyle::new(14.0).align(HAlign::Left, VAlign::Bottom);
        let mut y = self.height as f32 - 12.0;
        for (i, s) in spatulas.iter().enumerate().rev() {
            if let Some(f) = s.force {
                let text = format!(
                    "{}: |F| = {:.3} N   ({:+.3}, {:+.3}, {:+.3}) N",
                    s.name,
                    f.norm(),
                    f.x,
                    f.y,
                    f.z
                )
                .replace('-', "\u{2212}");
                draw_text(&mut img, &text, 18.0, y, &st.colour(ARROWS[i % 2]));
                y -= 20.0;
            }
        }
        let (vw, vh) = (view.width(), view.height());
        for (i, a) in &arrows {
            let s = &spatulas[*i];
            let Some(f) = s.force else { continue };
            let base = Point3::from(s.pose.translation.vector);
            let tip = base + f * scale;
            label_arrow(
                &mut img,
                &cam,
                (vw, vh),
                &base,
                &tip,
                &s.name,
                a.colour,
                16.0,
            );
        }
        Ok(img)
    }
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
