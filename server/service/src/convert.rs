//! Conversions between engine values and `fissure.v1` messages.

use fissure_engine::collide::tool::instrument::{Plate, PlateShape};
use fissure_engine::scene::{ContactLaw, Scene, Strategy};
use fissure_engine::sim::ForceOut;
use fissure_engine::sim::core::engine::Model;
use fissure_engine::sim::core::pose::{PoseError, RawPose};
use fissure_engine::sim::core::snapshot::{Frame, InstrumentReaction};
use fissure_engine::sim::runtime::stats::{LatencySummary, StatsSummary};
use fissure_proto::v1 as pb;
use nalgebra::Vector3;

/// A vector message from an engine vector.
pub fn vec3(v: &Vector3<f64>) -> pb::Vec3 {
    pb::Vec3 {
        x: v.x,
        y: v.y,
        z: v.z,
    }
}

/// A plate's drawn surface ([`Plate::outline`]) in the instrument frame.
fn plate_outline(plate: &Plate) -> pb::SurfaceMesh {
    let (points, triangles) = plate.outline();
    pb::SurfaceMesh {
        rest_positions_m: points.iter().flat_map(|p| [p.x, p.y, p.z]).collect(),
        triangles: triangles.into_iter().flatten().collect(),
        triangle_labels: Vec::new(),
    }
}

fn arr3(v: [f64; 3]) -> pb::Vec3 {
    pb::Vec3 {
        x: v[0],
        y: v[1],
        z: v[2],
    }
}

fn quat(q: [f64; 4]) -> pb::Quaternion {
    pb::Quaternion {
        w: q[0],
        x: q[1],
        y: q[2],
        z: q[3],
    }
}

/// The constitutive model a strategy solves (`Material.model`): the linear
/// strategies share one, each nonlinear one names its own.
fn material_model(strategy: Strategy) -> &'static str {
    strategy.kind().material_model
}

/// The description of a loaded scene.
pub fn scene_description(scene: &Scene, model: &Model) -> pb::SceneDescription {
    let (lo, hi) = model.mesh.bounds();
    pb::SceneDescription {
        name: scene.name.clone(),
        description: scene.description.clone(),
        units: "SI".into(),
        material: Some(pb::Material {
            model: material_model(scene.solver.strategy).into(),
            youngs_modulus_pa: scene.material.youngs_modulus_pa,
            poisson_ratio: scene.material.poisson_ratio,
            element: scene.solver.element.name().into(),
        }),
        instruments: scene
            .instruments
            .iter()
            .enumerate()
            .map(|(i, ins)| {
                let edge = ins.shape.cutting_edge(ins.width_m, ins.length_m);
                pb::InstrumentDescription {
                    name: ins.name.clone(),
                    shape: ins.shape.name().into(),
                    thickness_m: ins.thickness_m,
                    width_m: ins.width_m,
                    length_m: ins.length_m,
                    nodes_per_face: ins.nodes_per_face,
                    rim_nodes: model.rim_node_count(i) as u32,
                    handle_m: Some(pb::Vec3 {
                        x: 0.0,
                        y: 0.0,
                        z: 0.0,
                    }),
                    home_position_m: Some(arr3(ins.home_position_m)),
                    home_orientation: Some(quat(ins.home_orientation)),
                    base_width_m: match ins.shape {
                        PlateShape::Trapezoid { base_width_m } => base_width_m,
                        _ => 0.0,
                    },
                    bend_radius_m: match ins.shape {
                        PlateShape::Curved { bend_radius_m } => bend_radius_m,
                        _ => 0.0,
                    },
                    cutting_edge_from_m: edge.map(|e| vec3(&e[0].coords)),
                    cutting_edge_to_m: edge.map(|e| vec3(&e[1].coords)),
                    // The plate the server collides with.
                    outline: Some(plate_outline(&model.instruments[i].plate)),
                }
            })
            .collect(),
        loops: Some(pb::LoopConfig {
            deformation_interval_s: scene.loops.deformation_interval_s,
            stepped: scene.loops.stepped,
            haptic_rate_hz: scene.loops.haptic_rate_hz,
        }),
        model: Some(pb::ModelSize {
            nodes: model.mesh.nodes.len() as u32,
            tetrahedra: model.mesh.tets.len() as u32,
            surface_vertices: model.surface.to_volume.len() as u32,
            surface_triangles: model.surface.triangles.len() as u32,
            bounds_min_m: Some(vec3(&lo.coords)),
            bounds_max_m: Some(vec3(&hi.coords)),
        }),
        solver: scene.solver.strategy.name().into(),
        collision_method: scene.collision.method.name().into(),
        collision_backend: scene.collision.backend.name().into(),
        history_mode: scene.collision.history.name().into(),
        collision_traversal: scene.collision.traversal.name().into(),
        ties: model
            .ties
            .iter()
            .map(|t| pb::TieDescription {
                vertex_a: model.from_volume[t.a as usize],
                vertex_b: model.from_volume[t.b as usize],
                kind: tie_kind(t.kind) as i32,
                rest_length_m: t.rest_length_m,
            })
            .collect(),
        assessment: Some(assessment(&scene.assessment)),
        contact_law: scene.contact.law.name().into(),
        friction_coefficient: match scene.contact.law {
            ContactLaw::Coulomb => scene.contact.friction_coefficient.unwrap_or(0.0),
            ContactLaw::Frictionless | ContactLaw::Paper => 0.0,
        },
    }
}

/// The rest surface.
pub fn surface(model: &Model) -> pb::SurfaceMesh {
    pb::SurfaceMesh {
        rest_positions_m: model
            .rest_surface
            .iter()
            .flat_map(|p| [p.x, p.y, p.z])
            .collect(),
        triangles: model.surface.triangles.iter().flat_map(|t| *t).collect(),
        triangle_labels: if model.mesh.labels.is_empty() {
            Vec::new()
        } else {
            model
                .surface
                .face_tets
                .iter()
                .map(|&e| model.mesh.labels[e as usize])
                .collect()
        },
    }
}

/// The status code of a rejected pose: `OUT_OF_RANGE` for a stepped pose
/// behind the session's clock (the client may resend it later in time),
/// `UNAVAILABLE` when the server could not answer (shutting down),
/// `INVALID_ARGUMENT` for a malformed pose.
pub fn pose_error_code(e: &PoseError) -> tonic::Code {
    match e {
        PoseError::BehindClock { .. } => tonic::Code::OutOfRange,
        PoseError::NotAnswered(_) => tonic::Code::Unavailable,
        PoseError::Missing(_)
        | PoseError::NonFinite { .. }
        | PoseError::NotUnit { .. }
        | PoseError::SequenceBack { .. }
        | PoseError::TimeBack { .. } => tonic::Code::InvalidArgument,
    }
}

/// A pose message to the engine's raw pose; a missing field is an error naming it.
pub fn raw_pose(p: &pb::PoseSample) -> Result<RawPose, PoseError> {
    let pos = p
        .position_m
        .as_ref()
        .ok_or(PoseError::Missing("position_m"))?;
    let q = p
        .orientation
        .as_ref()
        .ok_or(PoseError::Missing("orientation"))?;
    Ok(RawPose {
        t_s: p.t_s,
        sequence: p.sequence,
        position_m: [pos.x, pos.y, pos.z],
        orientation: [q.w, q.x, q.y, q.z],
    })
}

/// A force sample message.
pub fn force_sample(f: &ForceOut) -> pb::ForceSample {
    pb::ForceSample {
        sequence: f.sequence,
        t_s: f.t_s,
        force_n: Some(vec3(&f.force_n)),
        torque_nm: Some(vec3(&f.torque_nm)),
        contact_count: f.contact_count,
        model_frame: f.model_frame,
        model_age_s: f.model_age_s,
        safety_flags: f.safety_flags,
        server_compute_us: f.compute_us,
        rejection: None,
    }
}

/// The answer to a rejected pose: zero force, the reason.
pub fn rejection(p: &pb::PoseSample, code: tonic::Code, message: String) -> pb::ForceSample {
    pb::ForceSample {
        sequence: p.sequence,
        t_s: p.t_s,
        force_n: Some(pb::Vec3::default()),
        torque_nm: Some(pb::Vec3::default()),
        rejection: Some(pb::PoseRejection {
            code: code as i32,
            message,
        }),
        ..Default::default()
    }
}

fn reaction(r: &InstrumentReaction) -> pb::InstrumentReaction {
    pb::InstrumentReaction {
        name: r.name.clone(),
        force_n: Some(vec3(&r.force_n)),
        torque_nm: Some(vec3(&r.torque_nm)),
        pairs: r.pairs,
        culled: r.culled,
        contact_vertices: r.contact_vertices,
        pending_vertices: r.pending_vertices,
        position_m: Some(vec3(&r.position_m)),
        orientation: Some(quat(r.orientation)),
        pressure: Some(pressure(&r.pressure)),
    }
}

fn pressure(p: &fissure_engine::sim::core::injury::Pressure) -> pb::RetractionPressure {
    pb::RetractionPressure {
        contact_area_m2: p.contact_area_m2,
        normal_force_n: p.normal_force_n,
        peak_pa: p.peak_pa,
        mean_pa: p.mean_pa,
        time_above_s: p.time_above_s,
        pressure_time_pa_s: p.pressure_time_pa_s,
    }
}

fn strain(f: &Frame, include_picture: bool) -> pb::TissueStrain {
    let s = &f.strain;
    pb::TissueStrain {
        max_principal: s.max_principal,
        at_m: Some(vec3(&s.at_m.coords)),
        volume_above_m3: s.volume_above_m3,
        threshold: s.threshold,
        picture: f
            .strain_picture
            .as_ref()
            .filter(|_| include_picture)
            .map(|p| pb::StrainPicture {
                positions_m: p.positions.iter().flat_map(|x| *x).collect(),
                strain: p.strain.clone(),
            }),
    }
}

fn levels(l: fissure_engine::scene::assessment::Levels) -> Option<pb::Levels> {
    Some(pb::Levels {
        warn: l.warn,
        fail: l.fail,
    })
}

/// The scene's assessment thresholds.
pub fn assessment(
    a: &fissure_engine::scene::assessment::AssessmentSpec,
) -> pb::AssessmentThresholds {
    pb::AssessmentThresholds {
        pressure_pa: levels(a.pressure_pa),
        time_above_s: levels(a.time_above_s),
        pressure_time_pa_s: levels(a.pressure_time_pa_s),
        strain: levels(a.strain),
        strained_volume_m3: levels(a.strained_volume_m3),
    }
}

/// A frame message, with or without positions and the strain picture.
pub fn frame(f: &Frame, include_positions: bool, include_picture: bool) -> pb::DeformationFrame {
    pb::DeformationFrame {
        frame: f.frame,
        sim_time_s: f.sim_time_s,
        positions_m: if include_positions {
            f.positions.iter().flat_map(|p| *p).collect()
        } else {
            Vec::new()
        },
        instruments: f.instruments.iter().map(reaction).collect(),
        timings: Some(pb::StepTimings {
            collision_us: f.timings.collision_us,
            solve_us: f.timings.solve_us,
            total_us: f.timings.total_us,
            assess_us: f.timings.assess_us,
        }),
        solver_error: f.solver_error.clone().unwrap_or_default(),
        max_displacement_m: f.max_displacement_m,
        rigid: Some(rigid_part(&f.rigid)),
        ties: tie_summary(&f.ties, &f.instruments),
        strain: Some(strain(f, include_picture)),
    }
}

fn tie_kind(k: fissure_engine::fem::ties::TieKind) -> pb::TieKind {
    match k {
        fissure_engine::fem::ties::TieKind::Trabecula => pb::TieKind::Trabecula,
        fissure_engine::fem::ties::TieKind::Vessel => pb::TieKind::Vessel,
    }
}

/// The ties of a frame (none: the scene has no ties and nothing went).
fn tie_summary(
    t: &fissure_engine::sim::core::snapshot::TieFrame,
    instruments: &[fissure_engine::sim::core::snapshot::InstrumentReaction],
) -> Option<pb::TieSummary> {
    use fissure_engine::sim::core::snapshot::TieCause;
    if t.trabeculae_intact == 0
        && t.vessels_intact == 0
        && t.events.is_empty()
        && t.released.is_empty()
    {
        return None;
    }
    Some(pb::TieSummary {
        trabeculae_intact: t.trabeculae_intact,
        vessels_intact: t.vessels_intact,
        released: t.released.clone(),
        events: t
            .events
            .iter()
            .map(|e| {
                let (cause, k) = match e.cause {
                    TieCause::Cut { instrument } => (pb::TieCause::Cut, instrument),
                    TieCause::Torn { instrument } => (pb::TieCause::Torn, instrument),
                };
                pb::TieEvent {
                    sim_time_s: e.sim_time_s,
                    tie: e.tie,
                    kind: tie_kind(e.kind) as i32,
                    cause: cause as i32,
                    instrument: instruments
                        .get(k as usize)
                        .map(|r| r.name.clone())
                        .unwrap_or_default(),
                    position_m: Some(vec3(&e.position_m.coords)),
                    strain: e.strain,
                }
            })
            .collect(),
    })
}

fn rigid_part(r: &fissure_engine::sim::core::motion::RigidPart) -> pb::RigidPart {
    pb::RigidPart {
        rotation_deg: r.rotation_deg,
        translation_m: Some(vec3(&r.translation_m)),
        max_rigid_m: r.max_rigid_m,
        centre_m: Some(vec3(&r.centre_m.coords)),
        near_radius_m: fissure_engine::sim::core::motion::NEAR_RADIUS_M,
        max_non_rigid_near_m: r.max_non_rigid_near_m,
        max_non_rigid_far_m: r.max_non_rigid_far_m,
    }
}

fn latency(l: &LatencySummary) -> pb::LatencySummary {
    pb::LatencySummary {
        count: l.count,
        p50_us: l.p50_us,
        p99_us: l.p99_us,
        max_us: l.max_us,
    }
}

/// A stats message.
pub fn stats(s: &StatsSummary) -> pb::Stats {
    pb::Stats {
        uptime_s: s.uptime_s,
        frames: s.frames,
        force_samples: s.force_samples,
        rejected_poses: s.rejected_poses,
        watchers: s.watchers,
        claimed: s.claimed.clone(),
        force_compute: Some(latency(&s.force_compute)),
        force_collision: Some(latency(&s.force_collision)),
        deformation_step: Some(latency(&s.deformation_step)),
        failed_steps: s.failed_steps,
        recording_lost: s.recording_lost,
        solver_cache_bytes: s.solver_cache_bytes,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `GetStats` carries every counter of the summary, the recorder's loss
    /// included.
    #[test]
    fn stats_carry_the_counters() {
        let s = StatsSummary {
            uptime_s: 2.5,
            frames: 40,
            force_samples: 2_000,
            rejected_poses: 3,
            watchers: 1,
            claimed: vec!["left".into()],
            failed_steps: 2,
            recording_lost: 12,
            solver_cache_bytes: 1 << 20,
            ..Default::default()
        };
        let m = stats(&s);
        assert_eq!(
            (
                m.uptime_s,
                m.frames,
                m.force_samples,
                m.rejected_poses,
                m.watchers,
                m.failed_steps,
                m.recording_lost,
                m.solver_cache_bytes
            ),
            (2.5, 40, 2_000, 3, 1, 2, 12, 1 << 20)
        );
        assert_eq!(m.claimed, ["left"]);
    }

    /// The description carries each plate's parameters, its true outline
    /// (posed by the instrument frame: the base ring at `z = 0`, the tip's
    /// at the plate's length) and a blade's cutting edge, so that a client
    /// draws the tool the server collides with.
    #[test]
    fn the_description_carries_each_shapes_outline_and_a_blades_edge() {
        use fissure_engine::collide::tool::instrument::PlateShape;
        let (mut scene, _) = Scene::load("cube").unwrap();
        let shapes = [
            PlateShape::Flat,
            PlateShape::Trapezoid {
                base_width_m: 0.5 * scene.instruments[0].width_m,
            },
            PlateShape::Curved {
                bend_radius_m: 4.0 * scene.instruments[0].length_m,
            },
            PlateShape::Blade,
        ];
        for shape in shapes {
            scene.instruments[0].shape = shape;
            let model = Model::build(&scene).unwrap();
            let d = scene_description(&scene, &model);
            let ins = &d.instruments[0];
            let spec = &scene.instruments[0];
            assert_eq!(ins.shape, shape.name());
            let mesh = ins.outline.as_ref().unwrap();
            let (points, triangles) = spec
                .shape
                .plate(spec.thickness_m, spec.width_m, spec.length_m)
                .outline();
            assert_eq!(mesh.rest_positions_m.len(), 3 * points.len());
            assert_eq!(mesh.triangles.len(), 3 * triangles.len());
            assert_eq!(
                mesh.rest_positions_m[2], 0.0,
                "{shape:?}: base at the handle"
            );
            let tip_z = mesh.rest_positions_m[mesh.rest_positions_m.len() - 1];
            if let PlateShape::Curved { bend_radius_m } = shape {
                // The last corner is face B's: half a thickness inside.
                let expected = (bend_radius_m - 0.5 * spec.thickness_m)
                    * (spec.length_m / bend_radius_m).sin();
                assert!(
                    (tip_z - expected).abs() < 1e-12,
                    "{shape:?}: tip at {tip_z}"
                );
            } else {
                assert_eq!(tip_z, spec.length_m, "{shape:?}");
            }
            match shape {
                PlateShape::Trapezoid { base_width_m } => {
                    assert_eq!(ins.base_width_m, base_width_m)
                }
                PlateShape::Curved { bend_radius_m } => {
                    assert_eq!(ins.bend_radius_m, bend_radius_m)
                }
                _ => assert_eq!((ins.base_width_m, ins.bend_radius_m), (0.0, 0.0)),
            }
            let edge = ins.cutting_edge_from_m.zip(ins.cutting_edge_to_m);
            assert_eq!(edge.is_some(), shape == PlateShape::Blade, "{shape:?}");
            if let Some((a, b)) = edge {
                let w2 = 0.5 * spec.width_m;
                assert_eq!(
                    [a.x, a.y, a.z, b.x, b.y, b.z],
                    [0.0, -w2, spec.length_m, 0.0, w2, spec.length_m]
                );
            }
        }
    }

    /// `Material.model` names the constitutive law a strategy solves: the
    /// two linear-elastic strategies share `linear`, each nonlinear one
    /// carries its scene-file name.
    #[test]
    fn material_models_name_the_law_of_each_strategy() {
        for s in Strategy::ALL {
            let expected = match s {
                Strategy::Direct | Strategy::Compliance => "linear",
                Strategy::Corotational | Strategy::NeoHookean => s.name(),
            };
            assert_eq!(material_model(s), expected, "{s:?}");
        }
    }
}
