//! One picture of a session: the deformed surface coloured by displacement
//! magnitude, the spatulas as plates, their reaction forces as arrows, a
//! title band and a legend panel.

use super::view::{ARROWS, ColourBy, STEEL, STEEL_CONTACT, SessionView, plate, tissue_colour};
use crate::render::draw::{fill_rect, line, stroke_rect};
use crate::render::raster::{
    Background, Camera, Colouring, EdgeStyle, MeshRef, RenderOptions, Renderer, TriMesh,
};
use crate::render::text::{HAlign, TextStyle, VAlign, draw_text};
use crate::render::{Image, RenderError, Rgb, ticks};
use fissure_proto::motion::RigidFit;
use fissure_proto::v1 as pb;
use nalgebra::Point3;

/// Height of the title band, px.
const TITLE_BAND: u32 = 58;
/// Width of the legend panel, px.
const PANEL: u32 = 120;

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

/// The colour scale: [`super::TISSUE_MAP`] from 0 (bottom) to `range_mm` (top).
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
