//! `fissure watch`: subscribes to a server's deformation frames and writes
//! what a person opens afterwards:
//!
//! * a VTU time series of the boundary surface (`surface-NNNNNN.vtu`, point
//!   data `displacement` in m) with its ParaView index `surface.pvd`
//!   (`timestep` = the frame's simulation time, s);
//! * PNG images of the deformed surface coloured by displacement magnitude
//!   (mm), with the spatulas as plates and their reaction forces as arrows
//!   (`frame-NNNNNN.png`);
//! * an animated GIF of the session (`session.gif`).
//!
//! The files are completed (the `.pvd` index, the last PNG, the GIF) however
//! the stream ends: the server shutting down, the connection failing,
//! `--max-frames`, `--duration-s` or Ctrl-C. A task reads the stream as fast
//! as it comes and keeps only the newest frame; the writer takes the newest
//! each time it is ready, so a watcher slower than the simulation stays
//! current and says how many frames it skipped ([`WatchReport::skipped`])
//! instead of falling behind.
//!
//! The pictures come from the headless software rasteriser of
//! [`crate::render`]; [`SessionView`] holds what they need (rest surface,
//! instruments, a camera per scene) and is shared with `fissure demo`.
//!
//! Colours: undisplaced tissue is a light pink ([`TISSUE_MAP`] at 0), deeper
//! displacement blends through salmon and orange-red to dark crimson, so
//! that the tissue reads as tissue and the deformation stands out.

use crate::render::draw::{fill_rect, line, stroke_rect};
use crate::render::raster::{
    Background, Camera, Colouring, EdgeStyle, MeshRef, RenderOptions, Renderer, TriMesh,
};
use crate::render::text::{HAlign, TextStyle, VAlign, draw_text};
use crate::render::{Image, RenderError, Rgb, anim, ticks};
use crate::replay::connect;
use anyhow::Context;
use fissure_proto::v1 as pb;
use fissure_server::sim::motion::RigidFit;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Options of `fissure watch`.
#[derive(Debug, Clone, clap::Args)]
pub struct WatchArgs {
    /// Server URL.
    #[arg(long, default_value = "http://127.0.0.1:50051")]
    pub server: String,
    /// Output folder (created; files in it are overwritten).
    #[arg(long, default_value = "fissure-out/watch")]
    pub out: PathBuf,
    /// Keep every Nth frame received (1 = all). Frames are latest-wins: a
    /// slow watcher already skips frames, this thins them further.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    pub every: u64,
    /// Stop after this many kept frames.
    #[arg(long)]
    pub max_frames: Option<usize>,
    /// Stop after this long, s (wall clock). Without a limit, watch until
    /// the server ends the stream (or shuts down), the connection fails, or
    /// Ctrl-C; the files are completed in every case.
    #[arg(long)]
    pub duration_s: Option<f64>,
    /// Image width, px (at least 320).
    #[arg(long, default_value_t = 960)]
    pub width: u32,
    /// Image height, px (at least 240).
    #[arg(long, default_value_t = 640)]
    pub height: u32,
    /// Write a PNG image of every kept frame (else only the first and last).
    #[arg(long)]
    pub png_all: bool,
    /// Largest number of GIF frames; above it the kept frames are thinned
    /// evenly (every 2nd, 4th, ...).
    #[arg(long, default_value_t = 150)]
    pub gif_frames: usize,
    /// Skip the VTU series.
    #[arg(long)]
    pub no_vtu: bool,
    /// Colour scale maximum, mm of displacement; by default the largest
    /// displacement seen so far (the scale then grows during the session).
    #[arg(long)]
    pub range_mm: Option<f64>,
    /// Camera azimuth about +z from +x, degrees (default: per scene).
    #[arg(long, allow_hyphen_values = true)]
    pub azimuth_deg: Option<f64>,
    /// Camera elevation above the xy plane, degrees (default: per scene).
    #[arg(long, allow_hyphen_values = true)]
    pub elevation_deg: Option<f64>,
    /// What the surface colour shows: `non-rigid` (the displacement left
    /// once the best-fit rigid motion of the surface is taken away) or
    /// `displacement` (from rest).
    #[arg(long, value_enum, default_value_t = ColourBy::NonRigid)]
    pub colour_by: ColourBy,
}

/// What the surface colour of a picture shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum ColourBy {
    /// The displacement left once the best-fit rigid motion of the surface
    /// is taken away ([`fissure_server::sim::motion`]).
    #[default]
    NonRigid,
    /// The displacement from rest.
    Displacement,
}

impl ColourBy {
    /// The legend's label.
    pub fn label(self) -> &'static str {
        match self {
            Self::NonRigid => "non-rigid displ.",
            Self::Displacement => "displacement",
        }
    }

    /// The largest value this colouring shows in `frame`, mm (the non-rigid
    /// one from the frame's rigid part; the total where the frame has none).
    pub fn peak_mm(self, frame: &pb::DeformationFrame) -> f64 {
        match (self, &frame.rigid) {
            (Self::NonRigid, Some(r)) => r.max_non_rigid_near_m.max(r.max_non_rigid_far_m) * 1e3,
            _ => frame.max_displacement_m * 1e3,
        }
    }
}

/// The tissue colour map: light pink at 0, salmon, orange-red, dark crimson
/// at 1 (sRGB stops, linear blend between them).
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
/// Force arrows, per instrument.
pub const ARROWS: [Rgb; 2] = [[20, 90, 220], [20, 150, 90]];

/// Height of the title band, px.
const TITLE_BAND: u32 = 58;
/// Width of the legend panel, px.
const PANEL: u32 = 120;

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

/// What the pictures of one session need: the rest surface, the
/// instruments and the camera.
#[derive(Debug, Clone)]
pub struct SessionView {
    /// Scene name.
    pub scene: String,
    /// Rest positions of the surface vertices, m.
    pub rest: Vec<Point3<f64>>,
    /// Surface triangles.
    pub triangles: Vec<[u32; 3]>,
    /// The scene's instruments.
    pub instruments: Vec<pb::InstrumentDescription>,
    /// Camera.
    pub camera: CameraPreset,
    /// What the surface colour shows.
    pub colour_by: ColourBy,
}

/// The pose of an instrument's handle point from proto fields (identity
/// rotation when the quaternion is missing or not finite).
pub fn pose_of(position: Option<&pb::Vec3>, q: Option<&pb::Quaternion>) -> Isometry3<f64> {
    let p = position.copied().unwrap_or_default();
    let rot = q
        .filter(|q| [q.w, q.x, q.y, q.z].iter().all(|v| v.is_finite()))
        .map(|q| UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q.w, q.x, q.y, q.z)))
        .unwrap_or_default();
    Isometry3::from_parts(Translation3::new(p.x, p.y, p.z), rot)
}

/// The plate of `ins` at handle pose `pose`: its centre pose (the plate runs
/// from the handle point along local +z) and half extents (thickness / 2,
/// width / 2, length / 2), m.
pub fn plate(
    ins: &pb::InstrumentDescription,
    pose: &Isometry3<f64>,
) -> (Isometry3<f64>, Vector3<f64>) {
    let centre = pose * Isometry3::translation(0.0, 0.0, 0.5 * ins.length_m);
    (
        centre,
        Vector3::new(0.5 * ins.thickness_m, 0.5 * ins.width_m, 0.5 * ins.length_m),
    )
}

impl SessionView {
    /// From the scene description and the rest surface; the camera is the
    /// scene's preset (see [`SessionView::preset`]).
    pub fn new(scene: &pb::SceneDescription, surface: &pb::SurfaceMesh) -> Self {
        let rest: Vec<Point3<f64>> = surface
            .rest_positions_m
            .chunks_exact(3)
            .map(|p| Point3::new(p[0], p[1], p[2]))
            .collect();
        let triangles: Vec<[u32; 3]> = surface
            .triangles
            .chunks_exact(3)
            .map(|t| [t[0], t[1], t[2]])
            .collect();
        let mut v = Self {
            scene: scene.name.clone(),
            rest,
            triangles,
            instruments: scene.instruments.clone(),
            camera: CameraPreset {
                azimuth_deg: -60.0,
                elevation_deg: 35.0,
                frame_box: (Point3::origin(), Point3::new(1.0, 1.0, 1.0)),
            },
            colour_by: ColourBy::default(),
        };
        v.camera = v.preset();
        v
    }

    /// The camera of the scene:
    /// * `sylvian`: from the left (x < 0), slightly above, framing the
    ///   fissure's entry (x = -65.7 mm, y = 10 mm, z = 0) and the plates, so
    ///   that the opened gap between the walls (which face +-z) is seen;
    /// * `interhemispheric`: from the front (-y) and above, framing the top
    ///   of the fissure;
    /// * `v-valley`, `u-valley`: along the groove from -y, a little above;
    /// * anything else: from the front-left and above, the whole model.
    pub fn preset(&self) -> CameraPreset {
        let (lo, hi) = crate::render::view::bounds(&self.rest);
        let homes = self.instruments.iter().flat_map(|ins| {
            let (c, h) = plate(
                ins,
                &pose_of(ins.home_position_m.as_ref(), ins.home_orientation.as_ref()),
            );
            (0..8).map(move |i| {
                c * Point3::new(
                    if i & 1 == 0 { -h.x } else { h.x },
                    if i & 2 == 0 { -h.y } else { h.y },
                    if i & 4 == 0 { -h.z } else { h.z },
                )
            })
        });
        let mut all = (lo, hi);
        for p in homes {
            all = (all.0.inf(&p), all.1.sup(&p));
        }
        let p = Point3::new;
        match self.scene.as_str() {
            "sylvian" => CameraPreset {
                azimuth_deg: 195.0,
                elevation_deg: 10.0,
                frame_box: (p(-0.103, -0.012, -0.014), p(-0.06, 0.032, 0.014)),
            },
            "interhemispheric" => CameraPreset {
                azimuth_deg: -70.0,
                elevation_deg: 45.0,
                frame_box: (p(-0.02, -0.03, 0.03), p(0.02, 0.03, 0.095)),
            },
            "v-valley" | "u-valley" => CameraPreset {
                azimuth_deg: -90.0,
                elevation_deg: 25.0,
                frame_box: all,
            },
            _ => CameraPreset {
                azimuth_deg: -60.0,
                elevation_deg: 35.0,
                frame_box: all,
            },
        }
    }

    /// Positions of `frame` (the rest surface when it carries none), into
    /// `out`.
    pub fn positions_into(&self, frame: &pb::DeformationFrame, out: &mut Vec<Point3<f64>>) {
        out.clear();
        if frame.positions_m.len() == 3 * self.rest.len() {
            out.extend(
                frame
                    .positions_m
                    .chunks_exact(3)
                    .map(|p| Point3::new(p[0] as f64, p[1] as f64, p[2] as f64)),
            );
        } else {
            out.extend_from_slice(&self.rest);
        }
    }

    /// The instruments' handle poses in `frame` (home poses for those it
    /// does not mention), with their reaction forces (N) and whether they
    /// touch tissue.
    pub fn instrument_states(
        &self,
        frame: &pb::DeformationFrame,
    ) -> Vec<(Isometry3<f64>, Option<Vector3<f64>>, bool)> {
        self.instruments
            .iter()
            .map(
                |ins| match frame.instruments.iter().find(|r| r.name == ins.name) {
                    Some(r) => {
                        let f = r.force_n.unwrap_or_default();
                        (
                            pose_of(r.position_m.as_ref(), r.orientation.as_ref()),
                            Some(Vector3::new(f.x, f.y, f.z)),
                            r.contact_vertices > 0,
                        )
                    }
                    None => (
                        pose_of(ins.home_position_m.as_ref(), ins.home_orientation.as_ref()),
                        None,
                        false,
                    ),
                },
            )
            .collect()
    }
}

/// Draws [`SessionView`] frames at one size, keeping buffers between frames.
pub struct FrameRenderer {
    width: u32,
    height: u32,
    renderer: Renderer,
    background: Background,
    positions: Vec<Point3<f64>>,
    colours: Vec<Rgb>,
}

/// What to write on a picture.
#[derive(Debug, Clone, PartialEq)]
pub struct Caption {
    /// Title (bold, top-left).
    pub title: String,
    /// Second line.
    pub subtitle: String,
    /// Displacement at the top of the colour scale, mm (> 0).
    pub range_mm: f64,
    /// Arrow length per newton, m/N; `None`: the largest force of the frame
    /// is drawn 30 % of the framed box's diagonal long.
    pub force_scale: Option<f64>,
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
            positions: Vec::new(),
            colours: Vec::new(),
        })
    }

    /// Draws `frame` of `view`: the surface coloured by displacement, the
    /// plates (blue-grey while touching tissue), force arrows and readouts,
    /// the caption and the colour scale.
    pub fn render(
        &mut self,
        view: &SessionView,
        frame: &pb::DeformationFrame,
        caption: &Caption,
    ) -> Result<Image, RenderError> {
        let mut positions = std::mem::take(&mut self.positions);
        view.positions_into(frame, &mut positions);
        let range = if caption.range_mm.is_finite() && caption.range_mm > 0.0 {
            caption.range_mm
        } else {
            1.0
        };
        self.colours.clear();
        match view.colour_by {
            ColourBy::Displacement => self.colours.extend(
                positions
                    .iter()
                    .zip(&view.rest)
                    .map(|(p, r)| tissue_colour((p - r).norm() * 1e3 / range)),
            ),
            ColourBy::NonRigid => {
                let fit = RigidFit::new(&view.rest, &positions);
                self.colours.extend(
                    positions
                        .iter()
                        .zip(&view.rest)
                        .map(|(p, r)| tissue_colour(fit.non_rigid(r, p).norm() * 1e3 / range)),
                );
            }
        }
        let states = view.instrument_states(frame);
        let plates: Vec<TriMesh> = view
            .instruments
            .iter()
            .zip(&states)
            .map(|(ins, (pose, _, touching))| {
                let (c, h) = plate(ins, pose);
                TriMesh::cuboid(&c, h, if *touching { STEEL_CONTACT } else { STEEL })
            })
            .collect();
        let (lo, hi) = view.camera.frame_box;
        let aspect = self.renderer.options().aspect();
        let cam = Camera::orbit_box(
            lo,
            hi,
            view.camera.azimuth_deg,
            view.camera.elevation_deg,
            30.0,
            aspect,
        );
        let diag = (hi - lo).norm();
        let fmax = states
            .iter()
            .filter_map(|s| s.1)
            .map(|f| f.norm())
            .filter(|f| f.is_finite())
            .fold(0.0, f64::max);
        let scale = caption
            .force_scale
            .unwrap_or(if fmax > 0.0 { 0.3 * diag / fmax } else { 0.0 });
        let arrows: Vec<(usize, TriMesh)> = states
            .iter()
            .enumerate()
            .filter_map(|(i, (pose, f, _))| {
                let f = (*f)?;
                let (c, _) = plate(&view.instruments[i], pose);
                let a = TriMesh::arrow(
                    c.translation.vector.into(),
                    f * scale,
                    0.008 * diag,
                    ARROWS[i % 2],
                );
                (!a.triangles.is_empty()).then_some((i, a))
            })
            .collect();
        let mut surface = MeshRef::new(
            &positions,
            &view.triangles,
            Colouring::PerVertex(&self.colours),
        )
        .with_specular(0.06);
        if view.triangles.len() < 4000 {
            surface = surface.with_edges(EdgeStyle {
                colour: [90, 40, 40],
                width: 0.35,
                opacity: 0.18,
            });
        }
        let mut meshes = vec![surface];
        meshes.extend(plates.iter().map(TriMesh::as_mesh));
        meshes.extend(arrows.iter().map(|(_, a)| a.as_mesh().on_top()));
        let picture = self.renderer.render(&cam, &meshes)?;
        drop(meshes);
        self.positions = positions;

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
        draw_legend(
            &mut img,
            (self.width - PANEL) as i64 + 16,
            TITLE_BAND as i64 + 34,
            ((self.height - TITLE_BAND) as i64 - 120).clamp(80, 360),
            range,
            view.colour_by.label(),
        );
        // Force readouts bottom-left, names at the arrow tips.
        let st = TextStyle::new(14.0).align(HAlign::Left, VAlign::Bottom);
        let mut y = self.height as f32 - 12.0;
        for (i, (_, f, touching)) in states.iter().enumerate().rev() {
            if let Some(f) = f {
                let text = format!(
                    "{}: |F| = {:.3} N   ({:+.3}, {:+.3}, {:+.3}) N{}",
                    view.instruments[i].name,
                    f.norm(),
                    f.x,
                    f.y,
                    f.z,
                    if *touching { "" } else { "   no contact" }
                )
                .replace('-', "\u{2212}");
                draw_text(&mut img, &text, 18.0, y, &st.colour(ARROWS[i % 2]));
                y -= 20.0;
            }
        }
        let (vw, vh) = (picture.width(), picture.height());
        for (i, a) in &arrows {
            let (pose, Some(f), _) = states[*i] else {
                continue;
            };
            let (c, _) = plate(&view.instruments[*i], &pose);
            let base = Point3::from(c.translation.vector);
            let tip = base + f * scale;
            crate::render::view::label_arrow(
                &mut img,
                &cam,
                (vw, vh),
                &base,
                &tip,
                &view.instruments[*i].name,
                a.colour,
                14.0,
            );
        }
        Ok(img)
    }
}

/// The colour scale: [`TISSUE_MAP`] from 0 (bottom) to `range_mm` (top).
fn draw_legend(img: &mut Image, x: i64, y: i64, bar_h: i64, range_mm: f64, label: &str) {
    let (bar_w, ink) = (18, [40, 40, 40]);
    for j in 0..bar_h {
        let t = 1.0 - (j as f64 + 0.5) / bar_h as f64;
        fill_rect(img, x, y + j, x + bar_w, y + j + 1, tissue_colour(t));
    }
    stroke_rect(img, x, y, x + bar_w, y + bar_h, [90, 90, 90]);
    let style = TextStyle::new(13.0)
        .colour(ink)
        .align(HAlign::Left, VAlign::Middle);
    let (ticks, _) = ticks::linear(0.0, range_mm, (bar_h / 45).clamp(2, 8) as usize);
    for t in ticks {
        let f = t.value / range_mm;
        if !(0.0..=1.0 + 1e-9).contains(&f) {
            continue;
        }
        let py = y as f64 + (1.0 - f) * (bar_h - 1) as f64 + 0.5;
        let right = (x + bar_w) as f64;
        line(img, [right - 4.0, py], [right + 3.0, py], 1.0, ink);
        draw_text(img, &t.label, (x + bar_w + 6) as f32, py as f32, &style);
    }
    let st = TextStyle::new(13.0)
        .colour(ink)
        .align(HAlign::Left, VAlign::Bottom);
    draw_text(img, label, (x - 6) as f32, (y - 22) as f32, &st);
    draw_text(img, "(mm)", (x - 6) as f32, (y - 7) as f32, &st);
}

/// A VTU time series of the surface with its `.pvd` index.
#[derive(Debug)]
pub struct VtuSeries {
    dir: PathBuf,
    stem: String,
    entries: Vec<(f64, String)>,
    positions: Vec<Point3<f64>>,
    displacement: Vec<Vector3<f64>>,
}

impl VtuSeries {
    /// A series written into `dir` as `<stem>-NNNNNN.vtu` and `<stem>.pvd`.
    pub fn new(dir: &Path, stem: &str) -> Self {
        Self {
            dir: dir.to_owned(),
            stem: stem.to_owned(),
            entries: Vec::new(),
            positions: Vec::new(),
            displacement: Vec::new(),
        }
    }

    /// Writes one frame: the deformed surface with point data
    /// `displacement` (m). Returns the file written.
    pub fn write(
        &mut self,
        view: &SessionView,
        frame: &pb::DeformationFrame,
    ) -> anyhow::Result<PathBuf> {
        view.positions_into(frame, &mut self.positions);
        self.displacement.clear();
        self.displacement
            .extend(self.positions.iter().zip(&view.rest).map(|(p, r)| p - r));
        let name = format!("{}-{:06}.vtu", self.stem, frame.frame);
        let path = self.dir.join(&name);
        let file =
            std::fs::File::create(&path).with_context(|| format!("creating {}", path.display()))?;
        let mut w = std::io::BufWriter::new(file);
        fissure_server::mesh::io::vtu::write_vtu_surface(
            &mut w,
            &self.positions,
            &view.triangles,
            &[("displacement", &self.displacement)],
            &[],
        )
        .and_then(|_| w.flush())
        .with_context(|| format!("writing {}", path.display()))?;
        self.entries.push((frame.sim_time_s, name));
        Ok(path)
    }

    /// Number of frames written.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether no frame was written.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Writes the `.pvd` index (ParaView's collection of the frames, with
    /// their simulation times in s) and returns its path.
    pub fn finish(&self) -> anyhow::Result<PathBuf> {
        let path = self.dir.join(format!("{}.pvd", self.stem));
        std::fs::write(&path, pvd(&self.entries))
            .with_context(|| format!("writing {}", path.display()))?;
        Ok(path)
    }
}

/// A ParaView collection file of `(time s, file)` entries.
pub fn pvd(entries: &[(f64, String)]) -> String {
    let mut s = String::from(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n<Collection>\n",
    );
    for (t, f) in entries {
        s.push_str(&format!(
            "<DataSet timestep=\"{t:.6}\" group=\"\" part=\"0\" file=\"{f}\"/>\n"
        ));
    }
    s.push_str("</Collection>\n</VTKFile>\n");
    s
}

/// GIF frames with a bound on their number: past `2 * cap` every other one
/// is dropped and the stride doubles, so the kept frames stay evenly spaced.
#[derive(Debug, Default)]
pub struct GifBuffer {
    cap: usize,
    stride: u64,
    seen: u64,
    frames: Vec<Image>,
}

impl GifBuffer {
    /// At most about `cap` frames (at least 2).
    pub fn new(cap: usize) -> Self {
        Self {
            cap: cap.max(2),
            stride: 1,
            seen: 0,
            frames: Vec::new(),
        }
    }

    /// Whether the next offered frame will be kept (render it only then).
    pub fn wants_next(&self) -> bool {
        self.seen % self.stride == 0
    }

    /// Offers the next frame (`None` when it was not rendered because
    /// [`GifBuffer::wants_next`] said no).
    pub fn push(&mut self, img: Option<Image>) {
        if let (true, Some(img)) = (self.wants_next(), img) {
            self.frames.push(img);
            if self.frames.len() >= 2 * self.cap {
                let mut k = 0;
                self.frames.retain(|_| {
                    k += 1;
                    k % 2 == 1
                });
                self.stride *= 2;
            }
        }
        self.seen += 1;
    }

    /// Frame interval of the kept frames in units of offered frames.
    pub fn stride(&self) -> u64 {
        self.stride
    }

    /// The kept frames.
    pub fn frames(&self) -> &[Image] {
        &self.frames
    }
}

/// GIF delay for frames `dt_s` apart in simulation time, hundredths of a
/// second (at least 2: browsers slow down shorter delays).
pub fn gif_delay_cs(dt_s: f64) -> u16 {
    if dt_s.is_finite() && dt_s > 0.0 {
        (dt_s * 100.0).round().clamp(2.0, 500.0) as u16
    } else {
        4
    }
}

/// How a watch ended.
#[derive(Debug, Clone, PartialEq)]
pub enum WatchEnd {
    /// `--max-frames` frames were kept.
    MaxFrames,
    /// `--duration-s` passed.
    Duration,
    /// Ctrl-C.
    Interrupted,
    /// The server ended the stream.
    ServerEnded,
    /// The server shut down (`UNAVAILABLE`, "the server is shutting down").
    ServerShutDown,
    /// The stream failed (connection lost, another status): the message.
    Failed(String),
}

impl std::fmt::Display for WatchEnd {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::MaxFrames => write!(f, "--max-frames reached"),
            Self::Duration => write!(f, "--duration-s passed"),
            Self::Interrupted => write!(f, "interrupted"),
            Self::ServerEnded => write!(f, "the server ended the stream"),
            Self::ServerShutDown => write!(f, "the server shut down"),
            Self::Failed(why) => write!(f, "the stream failed: {why}"),
        }
    }
}

/// What `fissure watch` wrote.
#[derive(Debug, Clone)]
pub struct WatchReport {
    /// Frames taken from the stream (the newest each time the writer was
    /// ready).
    pub received: usize,
    /// Frames kept (every Nth of those received).
    pub kept: usize,
    /// Frame numbers between the first and the last frame received that
    /// were never received: skipped by the server (latest-wins) or replaced
    /// by a newer one before the writer was ready.
    pub skipped: u64,
    /// Numbers of the first and the last frame received.
    pub frames: Option<(u64, u64)>,
    /// Why the watch ended.
    pub ended: WatchEnd,
    /// Files written.
    pub files: Vec<PathBuf>,
}

/// Reads `stream` into a latest-wins slot until it ends; returns how.
async fn receive(
    mut stream: tonic::Streaming<pb::DeformationFrame>,
    slot: tokio::sync::watch::Sender<Option<pb::DeformationFrame>>,
) -> WatchEnd {
    loop {
        match stream.message().await {
            Ok(Some(f)) => {
                slot.send_replace(Some(f));
            }
            Ok(None) => return WatchEnd::ServerEnded,
            Err(status)
                if status.code() == tonic::Code::Unavailable
                    && status.message().contains("shutting down") =>
            {
                return WatchEnd::ServerShutDown;
            }
            Err(status) => return WatchEnd::Failed(status.to_string()),
        }
    }
}

/// Runs `fissure watch`.
pub async fn run(args: &WatchArgs) -> anyhow::Result<WatchReport> {
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let mut client = connect(&args.server).await?;
    let scene = client
        .get_scene(pb::GetSceneRequest {})
        .await
        .context("GetScene")?
        .into_inner();
    let surface = client
        .get_surface(pb::GetSurfaceRequest {})
        .await
        .context("GetSurface")?
        .into_inner();
    let mut view = SessionView::new(&scene, &surface);
    view.colour_by = args.colour_by;
    if let Some(a) = args.azimuth_deg {
        view.camera.azimuth_deg = a;
    }
    if let Some(e) = args.elevation_deg {
        view.camera.elevation_deg = e;
    }
    let stream = client
        .watch(pb::WatchRequest {
            include_positions: true,
        })
        .await
        .context("Watch")?
        .into_inner();
    let mut renderer = FrameRenderer::new(args.width, args.height)?;
    let mut gif_renderer = FrameRenderer::new(args.width.min(640), args.height.min(427))?;
    let mut series = VtuSeries::new(&args.out, "surface");
    let mut gif = GifBuffer::new(args.gif_frames);
    let (slot, mut latest) = tokio::sync::watch::channel(None);
    let receiver = tokio::spawn(receive(stream, slot));
    let mut report = WatchReport {
        received: 0,
        kept: 0,
        skipped: 0,
        frames: None,
        ended: WatchEnd::ServerEnded,
        files: Vec::new(),
    };
    let mut max_mm: f64 = 0.0;
    let mut last: Option<pb::DeformationFrame> = None;
    let mut times = Vec::new();
    let deadline = args
        .duration_s
        .map(|d| Instant::now() + Duration::from_secs_f64(d.max(0.0)));
    let ctrl_c = tokio::signal::ctrl_c();
    tokio::pin!(ctrl_c);
    let mut ended = None;
    while ended.is_none() {
        let timeout = async {
            match deadline {
                Some(d) => tokio::time::sleep_until(d.into()).await,
                None => std::future::pending().await,
            }
        };
        let frame = tokio::select! {
            changed = latest.changed() => match changed {
                Ok(()) => latest.borrow_and_update().clone(),
                // The stream ended and its last frame was taken.
                Err(_) => break,
            },
            _ = timeout => { ended = Some(WatchEnd::Duration); None }
            _ = &mut ctrl_c => { ended = Some(WatchEnd::Interrupted); None }
        };
        let Some(frame) = frame else { continue };
        report.received += 1;
        report.frames = Some(match report.frames {
            None => (frame.frame, frame.frame),
            Some((first, prev)) => {
                report.skipped += frame.frame.saturating_sub(prev + 1);
                (first, frame.frame.max(prev))
            }
        });
        if (report.received as u64 - 1) % args.every != 0 {
            continue;
        }
        report.kept += 1;
        max_mm = max_mm.max(args.colour_by.peak_mm(&frame));
        let range_mm = args.range_mm.unwrap_or(max_mm.max(0.1));
        let caption = caption_of(&scene.name, &frame, range_mm);
        if !args.no_vtu {
            series.write(&view, &frame)?;
        }
        if args.png_all || report.kept == 1 {
            let path = args.out.join(format!("frame-{:06}.png", frame.frame));
            renderer.render(&view, &frame, &caption)?.save_png(&path)?;
            report.files.push(path);
        }
        let img = if gif.wants_next() {
            Some(gif_renderer.render(&view, &frame, &caption)?)
        } else {
            None
        };
        gif.push(img);
        times.push(frame.sim_time_s);
        last = Some(frame);
        if args.max_frames.is_some_and(|m| report.kept >= m) {
            ended = Some(WatchEnd::MaxFrames);
        }
    }
    report.ended = match ended {
        Some(e) => {
            receiver.abort();
            e
        }
        None => receiver
            .await
            .unwrap_or_else(|e| WatchEnd::Failed(e.to_string())),
    };
    if let Some(frame) = &last {
        if !args.png_all && report.kept > 1 {
            let range_mm = args.range_mm.unwrap_or(max_mm.max(0.1));
            let path = args.out.join(format!("frame-{:06}.png", frame.frame));
            renderer
                .render(&view, frame, &caption_of(&scene.name, frame, range_mm))?
                .save_png(&path)?;
            report.files.push(path);
        }
    }
    if !series.is_empty() {
        report.files.push(series.finish()?);
    }
    if !gif.frames().is_empty() {
        let dt = if times.len() > 1 {
            (times[times.len() - 1] - times[0]) / (times.len() - 1) as f64
        } else {
            0.04
        };
        let path = args.out.join("session.gif");
        anim::save_gif(
            gif.frames(),
            &path,
            &anim::GifOptions {
                delay_cs: gif_delay_cs(dt * gif.stride() as f64),
                ..Default::default()
            },
        )?;
        report.files.push(path);
    }
    let span = report
        .frames
        .map_or(String::new(), |(a, b)| format!(" (frames {a}..{b})"));
    let skipped = if report.skipped > 0 {
        " (latest-wins: frames came faster than this watcher wrote them)"
    } else {
        ""
    };
    println!(
        "{}: {} frames received{span}, {} kept, {} skipped{skipped}; {} VTU files (+ surface.pvd) in {}",
        report.ended,
        report.received,
        report.kept,
        report.skipped,
        series.len(),
        args.out.display()
    );
    for f in &report.files {
        println!("  {}", f.display());
    }
    if let WatchEnd::Failed(why) = &report.ended {
        anyhow::bail!(
            "the frame stream failed: {why} (the files written so far are completed, {} of them)",
            report.files.len()
        );
    }
    Ok(report)
}

/// Title and subtitle of a frame.
pub fn caption_of(scene: &str, frame: &pb::DeformationFrame, range_mm: f64) -> Caption {
    Caption {
        title: format!("fissure \u{2014} {scene}"),
        subtitle: format!(
            "frame {}   t = {:.3} s   max displacement {:.2} mm{}",
            frame.frame,
            frame.sim_time_s,
            frame.max_displacement_m * 1e3,
            if frame.solver_error.is_empty() {
                String::new()
            } else {
                format!("   step failed: {}", frame.solver_error)
            }
        ),
        range_mm,
        force_scale: None,
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
    fn gif_buffer_stays_bounded_and_even() {
        let img = Image::new(2, 2, [0; 3]).unwrap();
        let mut g = GifBuffer::new(10);
        for _ in 0..1000 {
            let want = g.wants_next();
            g.push(want.then(|| img.clone()));
        }
        assert!(g.frames().len() < 20 && g.frames().len() >= 10);
        // 1000 frames with stride s keep ceil(1000 / s) minus the dropped.
        assert_eq!(g.frames().len() as u64, 1000_u64.div_ceil(g.stride()));
    }

    #[test]
    fn pvd_lists_files_with_times() {
        let s = pvd(&[(0.0, "a-000000.vtu".into()), (0.02, "a-000001.vtu".into())]);
        assert!(s.contains(
            "<DataSet timestep=\"0.020000\" group=\"\" part=\"0\" file=\"a-000001.vtu\"/>"
        ));
        assert!(s.starts_with("<?xml"));
    }
}
