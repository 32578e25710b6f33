//! Runs one configuration of the study in-process, deterministically, on
//! the product's own stepped runner ([`SteppedRunner`]): the same collision
//! stage, contact rows, contact solve and force loops as the server's
//! stepped mode, so the study measures the product. The scenario's poses
//! are given to the runner time by time (both instruments at once); a
//! deformation step `k` happens at `t_0 + k dt` with, per instrument, the
//! latest pose with `t <= t_k`; a force sample at pose time `t` uses the
//! state of the last step strictly before `t`.
//!
//! What the study needs beyond the server's answers comes from the runner's
//! step records: every node's displacement (for the element inversion
//! measure and the surface error), the solver's iteration count and the
//! step times. A GPU ray backend is injected into the runner's collision
//! stages; a region of interest is the scene's (`roi`), whose displacements
//! are mapped back onto the whole model's surface for the comparison.
//!
//! Timings: a deformation step is the collision of all instruments, the
//! contact rows, the solve and the compliance patch of the force loops; a
//! force sample is one instrument's collision query and its coupled
//! contact solve, as in the server.

// Negated comparisons are deliberate: NaN must fail the checks.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::config::{Backend, Config, FISSURE_CENTRE_M};
use super::scenario::Scenario;
use fissure_engine::collide::RayBackend;
use fissure_engine::collide::rays::brute::BruteForce;
use fissure_engine::collide::rays::bvh::Bvh;
use fissure_engine::fem::compliance::ColumnPolicy;
use fissure_engine::mesh::TetMesh;
use fissure_engine::scene::RoiSpec;
use fissure_engine::sim::core::engine::{Model, StepEngine};
use fissure_engine::sim::core::force_loop::ForceLoop;
use fissure_engine::sim::core::stepped::{Answer, StepDone, SteppedRunner};
use nalgebra::{Isometry3, Matrix3, Point3, Vector3};
use std::time::Instant;

/// Deformation steps with `k dt <= end` (k >= 1), counted with the same
/// products `k as f64 * dt` as the server.
pub fn steps_until(end_s: f64, dt_s: f64) -> usize {
    let mut k = 0usize;
    while ((k + 1) as f64) * dt_s <= end_s + 1e-12 {
        k += 1;
    }
    k
}

/// What one run measured.
#[derive(Debug, Clone)]
pub struct RunResult {
    /// The configuration.
    pub config: Config,
    /// Tetrahedra of the solved mesh (the crop with a region of interest).
    pub tets: usize,
    /// Nodes of the solved mesh.
    pub nodes: usize,
    /// Rest surface of the full model, m.
    pub rest_surface: Vec<Point3<f64>>,
    /// Its triangles.
    pub triangles: Vec<[u32; 3]>,
    /// Step times, s.
    pub step_t: Vec<f64>,
    /// Net force of the tissue on each instrument at each step, N
    /// (`[step][instrument]`).
    pub step_force: Vec<Vec<Vector3<f64>>>,
    /// Surface displacement at each step, m (`[step][surface vertex]`), when kept.
    pub surface_u: Vec<Vec<Vector3<f64>>>,
    /// Time per deformation step, ms.
    pub step_ms: Vec<f64>,
    /// Collision part of each step, ms.
    pub collision_ms: Vec<f64>,
    /// Whether each step failed (it then holds the last good state; empty
    /// in result files written before it was recorded).
    pub step_failed: Vec<bool>,
    /// Solver iterations per successful step.
    pub iterations: Vec<u32>,
    /// Force-loop samples: time, s, and force per instrument, N.
    pub sample_t: Vec<f64>,
    /// `[sample][instrument]`.
    pub sample_force: Vec<Vec<Vector3<f64>>>,
    /// Time per force sample (one instrument), us.
    pub sample_us: Vec<f64>,
    /// Smallest volume ratio `det F` over all elements and steps.
    pub min_det_f: f64,
    /// Every displacement and force finite.
    pub finite: bool,
    /// Failed steps (the state is held at the last good one).
    pub failed_steps: usize,
    /// First failure message.
    pub failure: Option<String>,
    /// Contact nodes outside the region of interest (the solved mesh does
    /// not have them: always 0 since the region of interest crops the
    /// collision surface too).
    pub dropped_outside_roi: usize,
    /// Building the model and the solver, ms.
    pub setup_ms: f64,
    /// Name of the ray backend actually used (`gpu-bvh (adapter)` or a CPU one).
    pub backend_used: String,
    /// Whether the strategy gives the force loop a compliance to solve on
    /// (otherwise the force loop holds the last step's force).
    pub has_local_model: bool,
}

/// Errors of a run's setup.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The scene could not be made.
    #[error("scene of {label}: {source}")]
    Scene {
        label: String,
        source: fissure_engine::scene::SceneError,
    },
    /// The model could not be built.
    #[error("model of {label}: {message}")]
    Model { label: String, message: String },
    /// The solver could not be built.
    #[error("solver of {label}: {message}")]
    Solver { label: String, message: String },
    /// The thread pool could not be built.
    #[error("thread pool of {label}: {message}")]
    Pool { label: String, message: String },
}

fn make_backend(kind: Backend, model: &Model) -> (Option<Box<dyn RayBackend>>, String) {
    let tris = &model.surface.triangles;
    let pos = &model.rest_surface;
    match kind {
        Backend::CpuBvh => (None, "cpu-bvh".into()),
        Backend::CpuBrute => (
            Some(Box::new(
                BruteForce::new(tris, pos).expect("the phantom surface is valid"),
            )),
            "cpu-brute".into(),
        ),
        Backend::GpuBvh => match fissure_engine::collide::rays::gpu::GpuBvh::try_new(tris, pos) {
            Ok(g) => {
                let name = format!("gpu-bvh ({})", g.adapter_name());
                (Some(Box::new(g)), name)
            }
            Err(e) => (
                Some(Box::new(
                    Bvh::new(tris, pos).expect("the phantom surface is valid"),
                )),
                format!("cpu-bvh (no GPU: {e})"),
            ),
        },
    }
}

/// Smallest `det F` (deformed over rest volume) over the elements of `mesh`
/// under node displacements `u` (m). `det F = det[x1-x0, x2-x0, x3-x0] /
/// det[X1-X0, X2-X0, X3-X0]`; `<= 0` means an inverted element.
pub fn min_det_f(mesh: &TetMesh, u: &[Vector3<f64>]) -> f64 {
    let mut worst = f64::INFINITY;
    for t in &mesh.tets {
        let x = |i: usize| mesh.nodes[t[i] as usize].coords;
        let y = |i: usize| x(i) + u[t[i] as usize];
        let rest = Matrix3::from_columns(&[x(1) - x(0), x(2) - x(0), x(3) - x(0)]).determinant();
        let def = Matrix3::from_columns(&[y(1) - y(0), y(2) - y(0), y(3) - y(0)]).determinant();
        let j = def / rest;
        if !(j >= worst) {
            worst = j;
        }
    }
    worst
}

/// Cache of built models, by the scene each was built from: a model is
/// reused only for an equal scene, since [`Model::build`] reads more of the
/// scene than the mesh (the material's modulus for the penalty stiffness,
/// the contact law and strategy for the shape the contact search runs on,
/// the collision method). A run therefore gets the model a process of its
/// own would build, bit for bit.
#[derive(Default)]
pub struct ModelCache {
    models: Vec<(fissure_engine::scene::Scene, std::sync::Arc<Model>)>,
}

impl ModelCache {
    /// The model of `config` on the scene `source` (built on first use);
    /// `roi` crops it.
    fn get_with(
        &mut self,
        config: &Config,
        source: &str,
        roi: Option<f64>,
    ) -> Result<std::sync::Arc<Model>, RunError> {
        let mut scene = config.scene_in(source).map_err(|source| RunError::Scene {
            label: config.label.clone(),
            source,
        })?;
        scene.roi = roi.map(|d| RoiSpec {
            centre_m: FISSURE_CENTRE_M,
            plane_normal: None,
            distance_m: d,
        });
        if let Some((_, m)) = self.models.iter().find(|(s, _)| *s == scene) {
            return Ok(m.clone());
        }
        let model = Model::build(&scene).map_err(|e| RunError::Model {
            label: config.label.clone(),
            message: e.to_string(),
        })?;
        let model = std::sync::Arc::new(model);
        self.models.push((scene, model.clone()));
        Ok(model)
    }

    /// The whole model of `config` on the scene `source` (no region of
    /// interest).
    pub fn get(
        &mut self,
        config: &Config,
        source: &str,
    ) -> Result<std::sync::Arc<Model>, RunError> {
        self.get_with(config, source, None)
    }
}

/// Runs `config` over `scenario` inside a rayon pool of `config.threads`
/// threads. `keep_surface` keeps every step's surface displacements (for
/// the accuracy comparison). `on_step` is called after each step.
pub fn run(
    config: &Config,
    scenario: &Scenario,
    models: &mut ModelCache,
    keep_surface: bool,
    on_step: &(dyn Fn() + Sync),
) -> Result<RunResult, RunError> {
    let t0 = Instant::now();
    let full = models.get(config, &scenario.scene)?;
    let model = models.get_with(config, &scenario.scene, config.roi_m)?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(config.threads.max(1))
        .build()
        .map_err(|e| RunError::Pool {
            label: config.label.clone(),
            message: e.to_string(),
        })?;
    pool.install(|| run_in_pool(config, scenario, &full, model, keep_surface, on_step, t0))
}

fn run_in_pool(
    config: &Config,
    scenario: &Scenario,
    full: &Model,
    model: std::sync::Arc<Model>,
    keep_surface: bool,
    on_step: &(dyn Fn() + Sync),
    t0: Instant,
) -> Result<RunResult, RunError> {
    let mut scene = config
        .scene_in(&scenario.scene)
        .map_err(|source| RunError::Scene {
            label: config.label.clone(),
            source,
        })?;
    scene.roi = config.roi_m.map(|d| RoiSpec {
        centre_m: FISSURE_CENTRE_M,
        plane_normal: None,
        distance_m: d,
    });
    scene.loops.deformation_interval_s = scenario.dt_s;
    let n_inst = model.instruments.len().min(scenario.tracks.len());
    let (backend, backend_used) = make_backend(config.backend, &model);
    let engine = StepEngine::new(&scene, model.clone(), ColumnPolicy::Compute, None, backend)
        .map_err(|e| RunError::Solver {
            label: config.label.clone(),
            message: e.to_string(),
        })?;
    let loops = (0..model.instruments.len())
        .map(|i| ForceLoop::new(&scene, &model, i, make_backend(config.backend, &model).0))
        .collect();
    let mut runner = SteppedRunner::new(&scene, engine, loops);
    let has_local_model = runner.snapshot().force_model.has_patch;
    let setup_ms = t0.elapsed().as_secs_f64() * 1e3;
    let total_steps = scenario.steps();
    let mut res = RunResult {
        config: config.clone(),
        tets: model.mesh.tets.len(),
        nodes: model.mesh.nodes.len(),
        rest_surface: full.rest_surface.clone(),
        triangles: full.surface.triangles.clone(),
        step_t: Vec::with_capacity(total_steps),
        step_force: Vec::with_capacity(total_steps),
        surface_u: Vec::new(),
        step_ms: Vec::with_capacity(total_steps),
        collision_ms: Vec::with_capacity(total_steps),
        step_failed: Vec::with_capacity(total_steps),
        iterations: Vec::new(),
        sample_t: Vec::with_capacity(scenario.times.len()),
        sample_force: Vec::with_capacity(scenario.times.len()),
        sample_us: Vec::with_capacity(scenario.times.len() * n_inst),
        min_det_f: 1.0,
        finite: true,
        failed_steps: 0,
        failure: None,
        dropped_outside_roi: 0,
        setup_ms,
        backend_used,
        has_local_model,
    };
    let n_full = full.mesh.nodes.len();
    let mut u_full = vec![Vector3::zeros(); n_full];
    let mut last_forces = vec![Vector3::zeros(); n_inst];
    let mut record = |done: &StepDone, res: &mut RunResult| {
        let snap = &done.snapshot;
        let frame = &snap.frame_summary;
        let mut forces: Vec<Vector3<f64>> = frame
            .instruments
            .iter()
            .take(n_inst)
            .map(|r| r.force_n)
            .collect();
        match (&done.report, &snap.solver_error) {
            (Some(rep), _) => res.iterations.push(rep.iterations),
            (None, Some(e)) => {
                res.failed_steps += 1;
                if res.failure.is_none() {
                    res.failure = Some(format!("step at t = {:.3} s: {e}", snap.sim_time_s));
                }
                forces.clone_from(&last_forces);
            }
            (None, None) => {}
        }
        last_forces.clone_from(&forces);
        let u = &snap.displacements;
        match &model.to_full {
            None => u_full.copy_from_slice(u),
            Some((map, _)) => {
                for (c, &f) in map.iter().enumerate() {
                    u_full[f as usize] = u[c];
                }
            }
        }
        let finite = u.iter().all(|v| v.iter().all(|c| c.is_finite()))
            && forces.iter().all(|f| f.iter().all(|c| c.is_finite()));
        res.finite &= finite;
        let j = min_det_f(&model.mesh, u);
        if !(j >= res.min_det_f) {
            res.min_det_f = j;
        }
        res.step_t.push(snap.sim_time_s);
        res.step_force.push(forces);
        res.step_ms.push(done.step_us * 1e-3);
        res.collision_ms.push(frame.timings.collision_us * 1e-3);
        res.step_failed
            .push(done.report.is_none() && snap.solver_error.is_some());
        if keep_surface {
            res.surface_u.push(
                full.surface
                    .to_volume
                    .iter()
                    .map(|&v| u_full[v as usize])
                    .collect(),
            );
        }
        on_step();
    };
    let mut answers: Vec<Answer> = Vec::new();
    let mut poses: Vec<(usize, Isometry3<f64>)> = Vec::with_capacity(n_inst);
    for (j, &t) in scenario.times.iter().enumerate() {
        poses.clear();
        poses.extend((0..n_inst).map(|i| (i, scenario.tracks[i].poses[j])));
        answers.clear();
        runner.tick(t, &poses, &mut |d| record(d, &mut res), &mut answers);
        let mut sample = vec![Vector3::zeros(); n_inst];
        for a in &answers {
            sample[a.instrument] = a.force.force_n;
            res.sample_us.push(a.compute_us);
        }
        res.finite &= sample.iter().all(|f| f.iter().all(|c| c.is_finite()));
        res.sample_t.push(t);
        res.sample_force.push(sample);
    }
    let end = scenario.times.first().copied().unwrap_or(0.0) + total_steps as f64 * scenario.dt_s;
    runner.finish(end, &mut |d| record(d, &mut res));
    Ok(res)
}

impl RunResult {
    /// The net force on each instrument at each step, for a force plot.
    pub fn forces_for_plot(&self) -> Vec<crate::client::render::plot::InstrumentForces> {
        ["left", "right"]
            .iter()
            .enumerate()
            .map(|(i, name)| crate::client::render::plot::InstrumentForces {
                name: (*name).to_string(),
                time: self.step_t.clone(),
                force: self
                    .step_force
                    .iter()
                    .map(|f| {
                        let v = f.get(i).copied().unwrap_or_else(Vector3::zeros);
                        [v.x, v.y, v.z]
                    })
                    .collect(),
            })
            .collect()
    }

    /// Mean of a slice (NaN when empty).
    pub fn mean(v: &[f64]) -> f64 {
        if v.is_empty() {
            f64::NAN
        } else {
            v.iter().sum::<f64>() / v.len() as f64
        }
    }

    /// Mean time per deformation step, ms.
    pub fn ms_per_step(&self) -> f64 {
        Self::mean(&self.step_ms)
    }

    /// Mean time per force sample, us.
    pub fn us_per_sample(&self) -> f64 {
        Self::mean(&self.sample_us)
    }

    /// Mean solver iterations per step.
    pub fn mean_iterations(&self) -> f64 {
        Self::mean(
            &self
                .iterations
                .iter()
                .map(|&i| i as f64)
                .collect::<Vec<_>>(),
        )
    }

    /// Largest solver iterations of a step.
    pub fn max_iterations(&self) -> u32 {
        self.iterations.iter().copied().max().unwrap_or(0)
    }

    /// The force samples against the steps at the same instants
    /// ([`super::haptic`]).
    pub fn haptic_error(&self) -> Option<super::haptic::HapticError> {
        super::haptic::at_step_instants(&super::haptic::Series {
            step_t: &self.step_t,
            step_force: &self.step_force,
            step_failed: &self.step_failed,
            sample_t: &self.sample_t,
            sample_force: &self.sample_force,
        })
    }

    /// Net force on instrument `i` at the last step, N.
    pub fn final_force(&self, i: usize) -> Vector3<f64> {
        self.step_force
            .last()
            .and_then(|f| f.get(i).copied())
            .unwrap_or_else(Vector3::zeros)
    }
}
