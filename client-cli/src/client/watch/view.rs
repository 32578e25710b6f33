//! What the pictures of a session need: the rest surface, the instruments
//! and the camera of each scene; and the translation of a session's frame
//! into the [`Scene`] that [`FrameRenderer`] draws.

use crate::client::render::frame::{
    CameraPreset, Caption, FrameRenderer, Outline, Plate, Scene, bounds,
};
use crate::client::render::{Image, RenderError};
use fissure_proto::v1 as pb;
use fissure_shared::motion::RigidFit;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

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
    /// Tissue label of each triangle (empty for a model of one tissue).
    pub triangle_labels: Vec<u32>,
    /// The scene's instruments.
    pub instruments: Vec<pb::InstrumentDescription>,
    /// Camera.
    pub camera: CameraPreset,
    /// What the surface colour shows.
    pub colour_by: ColourBy,
    /// The ties across the fissure (the scene's `[[ties]]`).
    pub ties: Vec<pb::TieDescription>,
}

/// The ties of a frame that hold, with their ends (m) at the frame's
/// surface positions `positions` and their strain `(L - L0) / L0`.
pub fn intact_ties(
    ties: &[pb::TieDescription],
    frame: &pb::DeformationFrame,
    positions: &[Point3<f64>],
) -> Vec<(Point3<f64>, Point3<f64>, pb::TieKind, f64)> {
    let released: &[u32] = frame.ties.as_ref().map_or(&[], |t| &t.released);
    ties.iter()
        .enumerate()
        .filter(|(i, _)| released.binary_search(&(*i as u32)).is_err())
        .filter_map(|(_, t)| {
            let a = *positions.get(t.vertex_a as usize)?;
            let b = *positions.get(t.vertex_b as usize)?;
            let strain = ((b - a).norm() - t.rest_length_m) / t.rest_length_m;
            Some((a, b, t.kind(), strain))
        })
        .collect()
}

/// What the surface colour of a picture shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum ColourBy {
    /// The displacement left once the best-fit rigid motion of the surface
    /// is taken away ([`fissure_shared::motion`]).
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

/// The plate's true surface (`InstrumentDescription.outline`) at handle
/// pose `pose`, m; `None` when the description has none or it is not a
/// finite, indexed triangle mesh (a server of an older proto, or a bad
/// message: the box is drawn then).
pub fn outline(ins: &pb::InstrumentDescription, pose: &Isometry3<f64>) -> Option<Outline> {
    let mesh = ins.outline.as_ref()?;
    let xyz = &mesh.rest_positions_m;
    if xyz.is_empty() || xyz.len() % 3 != 0 || mesh.triangles.len() % 3 != 0 {
        return None;
    }
    if !xyz.iter().all(|v| v.is_finite()) {
        return None;
    }
    let n = (xyz.len() / 3) as u32;
    if mesh.triangles.is_empty() || mesh.triangles.iter().any(|&i| i >= n) {
        return None;
    }
    let points = xyz
        .chunks_exact(3)
        .map(|c| pose * Point3::new(c[0], c[1], c[2]))
        .collect();
    let triangles = mesh
        .triangles
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    Some((points, triangles))
}

/// A blade's cutting edge at handle pose `pose`, m; `None` for shapes that
/// do not cut.
pub fn cutting_edge(
    ins: &pb::InstrumentDescription,
    pose: &Isometry3<f64>,
) -> Option<[Point3<f64>; 2]> {
    let at = |v: &pb::Vec3| pose * Point3::new(v.x, v.y, v.z);
    let (a, b) = (
        at(ins.cutting_edge_from_m.as_ref()?),
        at(ins.cutting_edge_to_m.as_ref()?),
    );
    (a.coords
        .iter()
        .chain(b.coords.iter())
        .all(|v| v.is_finite()))
    .then_some([a, b])
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
            triangle_labels: if surface.triangle_labels.len() == triangles.len() {
                surface.triangle_labels.clone()
            } else {
                Vec::new()
            },
            rest,
            triangles,
            instruments: scene.instruments.clone(),
            ties: scene.ties.clone(),
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
        let (lo, hi) = bounds(&self.rest);
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
            "sylvian" | "sylvian-arachnoid" => CameraPreset {
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

impl SessionView {
    /// Draws `frame` with `renderer`: the surface coloured by
    /// [`SessionView::colour_by`] (mm), the plates at the frame's poses with
    /// their forces, under `caption`.
    pub fn render(
        &self,
        renderer: &mut FrameRenderer,
        frame: &pb::DeformationFrame,
        caption: &Caption,
    ) -> Result<Image, RenderError> {
        let mut positions = Vec::with_capacity(self.rest.len());
        self.positions_into(frame, &mut positions);
        let values_mm: Vec<f64> = match self.colour_by {
            ColourBy::Displacement => positions
                .iter()
                .zip(&self.rest)
                .map(|(p, r)| (p - r).norm() * 1e3)
                .collect(),
            ColourBy::NonRigid => {
                let fit = RigidFit::new(&self.rest, &positions);
                positions
                    .iter()
                    .zip(&self.rest)
                    .map(|(p, r)| fit.non_rigid(r, p).norm() * 1e3)
                    .collect()
            }
        };
        self.render_values(
            renderer,
            frame,
            &values_mm,
            self.colour_by.label(),
            "(mm)",
            caption,
        )
    }

    /// Draws `frame` with `renderer`, the surface coloured by `values` (one
    /// per surface vertex, on the caption's scale, in `unit`) and labelled
    /// `quantity`, the plates at the frame's poses with their forces.
    pub fn render_values(
        &self,
        renderer: &mut FrameRenderer,
        frame: &pb::DeformationFrame,
        values: &[f64],
        quantity: &str,
        unit: &str,
        caption: &Caption,
    ) -> Result<Image, RenderError> {
        let mut positions = Vec::with_capacity(self.rest.len());
        self.positions_into(frame, &mut positions);
        let plates: Vec<Plate> = self
            .instruments
            .iter()
            .zip(self.instrument_states(frame))
            .map(|(ins, (pose, force, touching))| {
                let (centre, half_extents) = plate(ins, &pose);
                Plate {
                    name: ins.name.clone(),
                    pose: centre,
                    half_extents,
                    outline: outline(ins, &pose),
                    cutting_edge: cutting_edge(ins, &pose),
                    force,
                    touching,
                }
            })
            .collect();
        let ties: Vec<crate::client::render::frame::TieSegment> =
            intact_ties(&self.ties, frame, &positions)
                .into_iter()
                .map(|(a, b, kind, _)| crate::client::render::frame::TieSegment {
                    a,
                    b,
                    vessel: kind == pb::TieKind::Vessel,
                })
                .collect();
        renderer.render(
            &Scene {
                positions: &positions,
                triangles: &self.triangles,
                values_mm: values,
                quantity,
                unit,
                plates: &plates,
                ties: &ties,
                camera: self.camera,
            },
            caption,
        )
    }
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

    fn described(points: Vec<f64>, triangles: Vec<u32>) -> pb::InstrumentDescription {
        pb::InstrumentDescription {
            outline: Some(pb::SurfaceMesh {
                rest_positions_m: points,
                triangles,
                triangle_labels: Vec::new(),
            }),
            cutting_edge_from_m: Some(pb::Vec3 {
                x: 0.0,
                y: -0.001,
                z: 0.04,
            }),
            cutting_edge_to_m: Some(pb::Vec3 {
                x: 0.0,
                y: 0.001,
                z: 0.04,
            }),
            ..Default::default()
        }
    }

    /// The outline and the cutting edge are drawn where the pose puts the
    /// instrument frame: a point `p` of the frame at `pose * p`.
    #[test]
    fn the_outline_and_edge_follow_the_instruments_pose() {
        let ins = described(
            vec![0.0, 0.0, 0.0, 0.0, 0.0, 0.04, 0.001, 0.0, 0.0],
            vec![0, 1, 2],
        );
        let pose = Isometry3::from_parts(
            Translation3::new(0.1, 0.2, 0.3),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), std::f64::consts::FRAC_PI_2),
        );
        let (points, triangles) = outline(&ins, &pose).unwrap();
        assert_eq!(triangles, vec![[0, 1, 2]]);
        // +z of the frame is +x of the scene under this pose.
        assert!((points[1] - Point3::new(0.14, 0.2, 0.3)).norm() < 1e-15);
        let [a, b] = cutting_edge(&ins, &pose).unwrap();
        assert!((a - Point3::new(0.14, 0.199, 0.3)).norm() < 1e-15);
        assert!((b - Point3::new(0.14, 0.201, 0.3)).norm() < 1e-15);
    }

    /// A description without a usable outline (none, an index past the
    /// vertices, a ragged list, a non-finite coordinate) draws the box: it
    /// never panics on a server's message.
    #[test]
    fn a_bad_outline_falls_back_to_the_box() {
        let pose = Isometry3::identity();
        assert!(outline(&pb::InstrumentDescription::default(), &pose).is_none());
        let bad = [
            described(vec![0.0; 9], vec![0, 1, 3]),
            described(vec![0.0; 8], vec![0, 1, 2]),
            described(vec![0.0; 9], vec![0, 1]),
            described(
                vec![0.0, 0.0, f64::NAN, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
                vec![0, 1, 2],
            ),
            described(vec![], vec![]),
        ];
        for ins in &bad {
            assert!(outline(ins, &pose).is_none(), "{:?}", ins.outline);
        }
        let no_edge = pb::InstrumentDescription::default();
        assert!(cutting_edge(&no_edge, &pose).is_none());
    }
}
