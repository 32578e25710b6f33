//! Runs one configuration of the study in-process, deterministically.
//!
//! The driver composes the stages the server's `Simulation` composes (the
//! scene's [`Model`], the collision stage, the FEM solver, the force loop's
//! local model) in one thread of control, in the order stepped mode defines:
//! deformation step `k` happens at `t_k = k dt` with, per instrument, the
//! latest pose with `t <= t_k` and the force-loop history after it; a force
//! sample at pose time `t` uses the state of step `ceil(t / dt) - 1`. It calls
//! the solver directly (not through `sim::engine::Deformer`) because the study
//! needs what the deformer hides: every node's displacement (for the element
//! inversion measure), the solver's iteration count, an injected ray backend
//! (GPU) and a cropped region of interest.
//!
//! Timings: a deformation step is the collision of all instruments, the FEM
//! solve and the local force model (the inverse of the compliance block); a
//! force sample is one instrument's collision query plus the local-model
//! reaction, as in `Claim::force_sample`.

// Negated comparisons are deliberate: NaN must fail the checks.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::config::{Backend, Config, FISSURE_CENTRE_M};
use super::scenario::Scenario;
use fissure_server::collide::RayBackend;
use fissure_server::collide::brute::BruteForce;
use fissure_server::collide::bvh::Bvh;
use fissure_server::collide::contact::{self, ContactOutput, DetectOptions, Tool, Workspace};
use fissure_server::collide::history::Stage;
use fissure_server::fem::roi::{RoiCentre, crop};
use fissure_server::fem::{self, DeformationSolver, Prescribed};
use fissure_server::mesh::TetMesh;
use fissure_server::sim::engine::{EnforcedByNode, History, Model};
use fissure_server::sim::local_model::{ForceModel, ForceWorkspace};
use nalgebra::{Isometry3, Matrix3, Point3, Vector3};
use std::collections::{HashMap, VecDeque};
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
    /// Contact nodes outside the region of interest (dropped), summed over steps.
    pub dropped_outside_roi: usize,
    /// Building the model and the solver, ms.
    pub setup_ms: f64,
    /// Name of the ray backend actually used (`gpu-bvh (adapter)` or a CPU one).
    pub backend_used: String,
    /// Whether the strategy gives the force loop a local model (otherwise
    /// the force loop reports no force between steps).
    pub has_local_model: bool,
}

/// Errors of a run's setup.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The scene could not be made.
    #[error("scene of {label}: {source}")]
    Scene {
        label: String,
        source: fissure_server::scene::SceneError,
    },
    /// The model could not be built.
    #[error("model of {label}: {message}")]
    Model { label: String, message: String },
    /// The solver could not be built.
    #[error("solver of {label}: {source}")]
    Solver {
        label: String,
        source: fem::SolveError,
    },
    /// The thread pool could not be built.
    #[error("thread pool of {label}: {message}")]
    Pool { label: String, message: String },
}

/// The collision stage of one loop with an injected backend (mirrors
/// `sim::engine::ContactQuery`).
struct Collision {
    backend: Box<dyn RayBackend>,
    fitted: Option<usize>,
    ws: Workspace,
    out: ContactOutput,
    opts: DetectOptions,
    by_node: EnforcedByNode,
}

fn make_backend(kind: Backend, model: &Model) -> (Box<dyn RayBackend>, String) {
    let tris = &model.surface.triangles;
    let pos = &model.rest_surface;
    let bvh = || -> Box<dyn RayBackend> {
        Box::new(Bvh::new(tris, pos).expect("the phantom surface is valid"))
    };
    match kind {
        Backend::CpuBvh => (bvh(), "cpu-bvh".into()),
        Backend::CpuBrute => (
            Box::new(BruteForce::new(tris, pos).expect("the phantom surface is valid")),
            "cpu-brute".into(),
        ),
        Backend::GpuBvh => match fissure_server::collide::gpu::GpuBvh::try_new(tris, pos) {
            Ok(g) => {
                let name = format!("gpu-bvh ({})", g.adapter_name());
                (Box::new(g), name)
            }
            Err(e) => (bvh(), format!("cpu-bvh (no GPU: {e})")),
        },
    }
}

impl Collision {
    fn new(kind: Backend, model: &Model) -> (Self, String) {
        let (backend, name) = make_backend(kind, model);
        (
            Self {
                backend,
                fitted: None,
                ws: Workspace::new(),
                out: ContactOutput::default(),
                opts: DetectOptions::default(),
                by_node: EnforcedByNode::default(),
            },
            name,
        )
    }

    fn fit(&mut self, version: usize, surface: &[Point3<f64>]) {
        if self.fitted != Some(version) {
            self.backend.update_positions(surface);
            self.fitted = Some(version);
        }
    }

    fn run(
        &mut self,
        model: &Model,
        version: usize,
        surface: &[Point3<f64>],
        tools: &mut [Tool<'_>],
        stage: Stage,
    ) {
        self.fit(version, surface);
        let q = contact::ContactQuery {
            positions: surface,
            rest: &model.rest_surface,
            triangles: &model.surface.triangles,
            to_volume: &model.surface.to_volume,
        };
        if contact::detect_many(
            self.backend.as_mut(),
            &q,
            tools,
            stage,
            &self.opts,
            &mut self.ws,
            &mut self.out,
        )
        .is_err()
        {
            self.out = ContactOutput::default();
        }
        self.by_node.rebuild(&self.out);
    }

    fn displacement_of(&self, node: u32) -> Option<Vector3<f64>> {
        self.by_node.get(node)
    }
}

/// The solver over the whole mesh or a crop, with the node maps.
struct Solver {
    inner: Box<dyn DeformationSolver>,
    /// Crop node -> full node (`None`: identity).
    to_full: Option<Vec<u32>>,
    /// Full node -> crop node (`u32::MAX` outside).
    to_crop: Option<Vec<u32>>,
    tets: usize,
    nodes: usize,
}

fn build_solver(config: &Config, model: &Model) -> Result<Solver, RunError> {
    let material = fem::Material {
        youngs_modulus_pa: config.youngs_pa,
        poisson_ratio: config.nu,
    };
    let mut options = fem::SolverOptions::default();
    options.iterative.tolerance = config.tolerance;
    options.iterative.max_outer = 30;
    let err = |source| RunError::Solver {
        label: config.label.clone(),
        source,
    };
    match config.roi_m {
        None => {
            let inner = fem::build_solver(
                config.strategy,
                &model.mesh,
                material,
                &model.fixed,
                &options,
            )
            .map_err(err)?;
            Ok(Solver {
                inner,
                to_full: None,
                to_crop: None,
                tets: model.mesh.tets.len(),
                nodes: model.mesh.nodes.len(),
            })
        }
        Some(d) => {
            let roi = crop(
                &model.mesh,
                RoiCentre::Point(Point3::from(FISSURE_CENTRE_M)),
                d,
                &model.fixed,
            )
            .map_err(err)?;
            let inner =
                fem::build_solver(config.strategy, &roi.mesh, material, &roi.fixed, &options)
                    .map_err(err)?;
            Ok(Solver {
                inner,
                tets: roi.mesh.tets.len(),
                nodes: roi.mesh.nodes.len(),
                to_full: Some(roi.to_full),
                to_crop: Some(roi.to_crop),
            })
        }
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

/// The local force model of a step, as `sim::engine` builds it, with node
/// indices of the full model.
fn force_model(
    local: &fem::LocalModel,
    contacts: &ContactOutput,
    to_full: Option<&[u32]>,
    mesh: &TetMesh,
) -> ForceModel {
    let mut fm = fissure_server::sim::engine::force_model_from(local, contacts, |n| {
        to_full.map_or(n, |map| map[n as usize])
    });
    fm.rest = fm.nodes.iter().map(|&n| mesh.nodes[n as usize]).collect();
    // A distinct id per built model (the force loop caches per model).
    fm.frame = NEXT_MODEL_ID.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    fm
}

static NEXT_MODEL_ID: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

/// Cache of built models by (preset, nodes a face): the phantom is generated
/// once per preset and instrument layout.
#[derive(Default)]
pub struct ModelCache {
    models: HashMap<(String, u32), std::sync::Arc<Model>>,
}

impl ModelCache {
    /// The model of `config` (built on first use).
    pub fn get(&mut self, config: &Config) -> Result<std::sync::Arc<Model>, RunError> {
        let key = (config.preset.clone(), config.nodes_per_face);
        if let Some(m) = self.models.get(&key) {
            return Ok(m.clone());
        }
        let scene = config.scene().map_err(|source| RunError::Scene {
            label: config.label.clone(),
            source,
        })?;
        let model = Model::build(&scene).map_err(|e| RunError::Model {
            label: config.label.clone(),
            message: e.to_string(),
        })?;
        let model = std::sync::Arc::new(model);
        self.models.insert(key, model.clone());
        Ok(model)
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
    let model = models.get(config)?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(config.threads.max(1))
        .build()
        .map_err(|e| RunError::Pool {
            label: config.label.clone(),
            message: e.to_string(),
        })?;
    pool.install(|| run_in_pool(config, scenario, &model, keep_surface, on_step, t0))
}

struct LoggedPose {
    t: f64,
    pose: Isometry3<f64>,
    history: History,
}

fn run_in_pool(
    config: &Config,
    scenario: &Scenario,
    model: &Model,
    keep_surface: bool,
    on_step: &(dyn Fn() + Sync),
    t0: Instant,
) -> Result<RunResult, RunError> {
    let n_inst = model.instruments.len().min(scenario.tracks.len());
    let mut solver = build_solver(config, model)?;
    let has_local_model = {
        // A zero-contact solve tells whether the strategy keeps a local model.
        let _ = solver.inner.solve(&[]);
        solver.inner.local_model().is_some()
    };
    let (mut step_col, backend_used) = Collision::new(config.backend, model);
    let mut force_cols: Vec<Collision> = (0..n_inst)
        .map(|_| Collision::new(config.backend, model).0)
        .collect();
    let setup_ms = t0.elapsed().as_secs_f64() * 1e3;

    let nn = model.mesh.nodes.len();
    let mut surface = model.rest_surface.clone();
    let mut version = 0usize;
    let mut u_full = vec![Vector3::zeros(); nn];
    let mut fm = ForceModel::default();
    let mut fws = ForceWorkspace::default();
    let mut force_hist: Vec<History> = (0..n_inst).map(|i| model.new_history(i)).collect();
    let mut own_hist: Vec<History> = force_hist.clone();
    let mut logs: Vec<VecDeque<LoggedPose>> = (0..n_inst).map(|_| VecDeque::new()).collect();
    let home: Vec<Isometry3<f64>> = scenario
        .tracks
        .iter()
        .map(|t| t.poses.first().copied().unwrap_or_default())
        .collect();
    let dt = scenario.dt_s;
    let total_steps = scenario.steps();
    let mut res = RunResult {
        config: config.clone(),
        tets: solver.tets,
        nodes: solver.nodes,
        rest_surface: model.rest_surface.clone(),
        triangles: model.surface.triangles.clone(),
        step_t: Vec::with_capacity(total_steps),
        step_force: Vec::with_capacity(total_steps),
        surface_u: Vec::new(),
        step_ms: Vec::with_capacity(total_steps),
        collision_ms: Vec::with_capacity(total_steps),
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
    let mut prescribed: Vec<Prescribed> = Vec::new();
    let mut kept: Vec<usize> = Vec::new();
    let mut k = 0usize;

    let mut step = |k: usize,
                    logs: &mut Vec<VecDeque<LoggedPose>>,
                    surface: &mut Vec<Point3<f64>>,
                    version: &mut usize,
                    u_full: &mut Vec<Vector3<f64>>,
                    fm: &mut ForceModel,
                    own_hist: &mut Vec<History>,
                    res: &mut RunResult| {
        let t_k = k as f64 * dt;
        let ts = Instant::now();
        // Per instrument: the latest logged pose with t <= t_k.
        let mut poses = Vec::with_capacity(n_inst);
        let mut hists: Vec<History> = Vec::with_capacity(n_inst);
        let mut own = vec![false; n_inst];
        for i in 0..n_inst {
            let log = &mut logs[i];
            while log.len() >= 2 && log[1].t <= t_k {
                log.pop_front();
            }
            match log.front() {
                Some(p) if p.t <= t_k => {
                    poses.push(p.pose);
                    hists.push(p.history.clone());
                }
                _ => {
                    poses.push(home[i]);
                    hists.push(own_hist[i].clone());
                    own[i] = true;
                }
            }
        }
        {
            let mut tools: Vec<Tool<'_>> = model
                .instruments
                .iter()
                .zip(&poses)
                .zip(hists.iter_mut())
                .map(|((instrument, pose), history)| Tool {
                    instrument,
                    pose: *pose,
                    history,
                })
                .collect();
            step_col.run(model, *version, surface, &mut tools, Stage::Deformation);
        }
        for i in 0..n_inst {
            if own[i] {
                own_hist[i] = hists[i].clone();
            }
        }
        let collision_ms = ts.elapsed().as_secs_f64() * 1e3;
        let contacts = &step_col.out;
        prescribed.clear();
        kept.clear();
        for (j, e) in contacts.enforced.iter().enumerate() {
            let node = match &solver.to_crop {
                None => e.volume_node,
                Some(map) => map[e.volume_node as usize],
            };
            if node == u32::MAX {
                res.dropped_outside_roi += 1;
                continue;
            }
            kept.push(j);
            prescribed.push(Prescribed {
                node,
                displacement: e.displacement,
            });
        }
        let solved = solver.inner.solve(&prescribed);
        let mut forces = vec![Vector3::zeros(); n_inst];
        match solved {
            Ok(sol) => {
                res.iterations.push(sol.iterations);
                match &solver.to_full {
                    None => u_full.copy_from_slice(&sol.displacements),
                    Some(map) => {
                        for (c, &f) in map.iter().enumerate() {
                            u_full[f as usize] = sol.displacements[c];
                        }
                    }
                }
                for (&j, r) in kept.iter().zip(&sol.reactions) {
                    let inst = contacts.enforced[j].instrument as usize;
                    if inst < n_inst {
                        forces[inst] -= r;
                    }
                }
                *fm = match solver.inner.local_model() {
                    Some(local) => {
                        force_model(local, contacts, solver.to_full.as_deref(), &model.mesh)
                    }
                    None => ForceModel::default(),
                };
            }
            Err(e) => {
                res.failed_steps += 1;
                if res.failure.is_none() {
                    res.failure = Some(format!("step {k} (t = {t_k:.3} s): {e}"));
                }
                forces = res
                    .step_force
                    .last()
                    .cloned()
                    .unwrap_or_else(|| vec![Vector3::zeros(); n_inst]);
            }
        }
        for (s, &v) in model.surface.to_volume.iter().enumerate() {
            surface[s] = model.rest_surface[s] + u_full[v as usize];
        }
        *version += 1;
        let step_ms = ts.elapsed().as_secs_f64() * 1e3;
        // Bookkeeping outside the timed part.
        let finite = u_full.iter().all(|u| u.iter().all(|c| c.is_finite()))
            && forces.iter().all(|f| f.iter().all(|c| c.is_finite()));
        res.finite &= finite;
        let j = min_det_f(&model.mesh, u_full);
        if !(j >= res.min_det_f) {
            res.min_det_f = j;
        }
        res.step_t.push(t_k);
        res.step_force.push(forces);
        res.step_ms.push(step_ms);
        res.collision_ms.push(collision_ms);
        if keep_surface {
            res.surface_u.push(
                model
                    .surface
                    .to_volume
                    .iter()
                    .map(|&v| u_full[v as usize])
                    .collect(),
            );
        }
        on_step();
    };

    for (j, &t) in scenario.times.iter().enumerate() {
        // Steps strictly before t.
        let need = fissure_server::sim::step_before(t, dt) as usize;
        while k < need.min(total_steps) {
            k += 1;
            step(
                k,
                &mut logs,
                &mut surface,
                &mut version,
                &mut u_full,
                &mut fm,
                &mut own_hist,
                &mut res,
            );
        }
        let mut sample = vec![Vector3::zeros(); n_inst];
        for i in 0..n_inst {
            let pose = scenario.tracks[i].poses[j];
            let ts = Instant::now();
            let col = &mut force_cols[i];
            {
                let mut tools = [Tool {
                    instrument: &model.instruments[i],
                    pose,
                    history: &mut force_hist[i],
                }];
                col.run(model, version, &surface, &mut tools, Stage::Force);
            }
            let f = fm.instrument_force(
                i as u16,
                |node| col.displacement_of(node),
                &pose.translation.vector,
                &mut fws,
            );
            res.sample_us.push(ts.elapsed().as_secs_f64() * 1e6);
            sample[i] = f.force;
            logs[i].push_back(LoggedPose {
                t,
                pose,
                history: force_hist[i].clone(),
            });
        }
        res.finite &= sample.iter().all(|f| f.iter().all(|c| c.is_finite()));
        res.sample_t.push(t);
        res.sample_force.push(sample);
    }
    while k < total_steps {
        k += 1;
        step(
            k,
            &mut logs,
            &mut surface,
            &mut version,
            &mut u_full,
            &mut fm,
            &mut own_hist,
            &mut res,
        );
    }
    Ok(res)
}

impl RunResult {
    /// The net force on each instrument at each step, for a force plot.
    pub fn forces_for_plot(&self) -> Vec<crate::render::plot::InstrumentForces> {
        ["left", "right"]
            .iter()
            .enumerate()
            .map(|(i, name)| crate::render::plot::InstrumentForces {
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

    /// Net force on instrument `i` at the last step, N.
    pub fn final_force(&self, i: usize) -> Vector3<f64> {
        self.step_force
            .last()
            .and_then(|f| f.get(i).copied())
            .unwrap_or_else(Vector3::zeros)
    }
}
