//! What the pictures of a session need: the rest surface, the instruments,
//! the camera of each scene, and the colours of tissue and spatulas.

use crate::render::Rgb;
use fissure_proto::v1 as pb;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

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

/// What the surface colour of a picture shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum ColourBy {
    /// The displacement left once the best-fit rigid motion of the surface
    /// is taken away ([`fissure_proto::motion`]).
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
}
