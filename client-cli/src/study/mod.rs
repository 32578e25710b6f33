//! `fissure study`: speed against accuracy of the simulation's configurations,
//! and stability at the extremes, on a fixed scripted scenario (the bundled
//! Sylvian opening, both spatulas, stepped).
//!
//! * **Grid** (not a full factorial): a baseline (paper-48k, linear
//!   `compliance`, 150 source nodes a face, whole brain, CPU BVH, 2 threads)
//!   and one-dimension-at-a-time sweeps around it: mesh preset, strategy
//!   (`corotational`, `neo-hookean`), solver tolerance, nodes a face, region
//!   of interest, ray backend, threads, and the contact law (the paper's
//!   projection beside the frictionless default). Every run is compared with
//!   the **reference**, the finest preset with `neo-hookean` at a tight
//!   tolerance and frictionless contact ([`compare`]).
//! * **Stability**: Poisson's ratio, Young's modulus and spatula speed swept
//!   to their extremes ([`stability`]); each run reports whether it stayed
//!   finite, the worst element volume ratio `min det F`, the solver
//!   iterations and its force error, and the checks a user relies on are
//!   evaluated (and asserted by the CI test of `--quick`).
//!
//! Cost control (documented in the report): the nominal window is the
//! insertion and the opening (0-1.4 s of the 2 s trajectories), force
//! samples run at `--rate-hz` (200 Hz by default) instead of 1 kHz, and
//! deformation steps every [`Plan::dt_s`] (50 ms, the scene has 20 ms).

pub mod compare;
pub mod config;
pub mod driver;
pub mod output;
pub mod scenario;
pub mod stability;

use compare::Errors;
use config::{Backend, Config};
use driver::{ModelCache, RunResult};
use fissure_server::fem::Strategy;
use fissure_server::scene::ContactLaw;
use indicatif::{ProgressBar, ProgressStyle};
use scenario::Scenario;
use serde::Serialize;
use std::path::PathBuf;
use std::time::Instant;

/// Arguments of `fissure study`.
#[derive(Debug, Clone, clap::Args)]
pub struct StudyArgs {
    /// Output folder (CSV, markdown, PNG plots).
    #[arg(long, default_value = "fissure-out/study")]
    pub out: PathBuf,
    /// The cheap variant: coarse preset only, short window (CI runs it).
    #[arg(long)]
    pub quick: bool,
    /// Print the rows as JSON on stdout.
    #[arg(long)]
    pub json: bool,
    /// Force-loop samples per second of simulated time.
    #[arg(long)]
    pub rate_hz: Option<f64>,
    /// Nominal window of the trajectory played, s (at most 2).
    #[arg(long)]
    pub window_s: Option<f64>,
    /// Skip the speed-accuracy grid.
    #[arg(long)]
    pub no_grid: bool,
    /// Skip the stability sweep.
    #[arg(long)]
    pub no_stability: bool,
    /// No progress bar.
    #[arg(long)]
    pub no_progress: bool,
}

/// One row of the grid or of the stability sweep.
#[derive(Debug, Clone, Serialize)]
pub struct Row {
    /// The configuration.
    #[serde(flatten)]
    pub config: Config,
    /// Ray backend actually used.
    pub backend_used: String,
    /// Mean handle speed, m/s.
    pub speed_mps: f64,
    /// Tetrahedra solved.
    pub tets: usize,
    /// Nodes solved.
    pub nodes: usize,
    /// Deformation steps.
    pub steps: usize,
    /// Mean time per deformation step, ms.
    pub ms_per_step: f64,
    /// Mean collision part of a step, ms.
    pub collision_ms: f64,
    /// Mean time per force sample (one instrument), us.
    pub us_per_sample: f64,
    /// 99th percentile of the force sample time, us.
    pub us_per_sample_p99: f64,
    /// Model and solver setup, ms.
    pub setup_ms: f64,
    /// Mean solver iterations a step.
    pub iterations_mean: f64,
    /// Largest solver iterations of a step.
    pub iterations_max: u32,
    /// Smallest element volume ratio over the run.
    pub min_det_f: f64,
    /// Every value finite.
    pub finite: bool,
    /// Failed steps.
    pub failed_steps: usize,
    /// First failure.
    pub failure: Option<String>,
    /// Whether the force loop has a local model (else no force between steps).
    pub haptic_local_model: bool,
    /// Net force magnitude on each instrument at the last step, N.
    pub final_force_n: [f64; 2],
    /// Errors against the reference (grid) or the sweep's nominal run (stability).
    pub errors: Option<Errors>,
    /// Contact nodes dropped outside the region of interest (all steps).
    pub dropped_outside_roi: usize,
}

fn percentile(v: &[f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s[((p * (s.len() - 1) as f64).round() as usize).min(s.len() - 1)]
}

impl Row {
    /// The row of a run.
    pub fn of(run: &RunResult, scenario: &Scenario, errors: Option<Errors>) -> Self {
        Self {
            config: run.config.clone(),
            backend_used: run.backend_used.clone(),
            speed_mps: scenario.mean_speed_mps,
            tets: run.tets,
            nodes: run.nodes,
            steps: run.step_t.len(),
            ms_per_step: run.ms_per_step(),
            collision_ms: RunResult::mean(&run.collision_ms),
            us_per_sample: run.us_per_sample(),
            us_per_sample_p99: percentile(&run.sample_us, 0.99),
            setup_ms: run.setup_ms,
            iterations_mean: run.mean_iterations(),
            iterations_max: run.max_iterations(),
            min_det_f: run.min_det_f,
            finite: run.finite,
            failed_steps: run.failed_steps,
            failure: run.failure.clone(),
            haptic_local_model: run.has_local_model,
            final_force_n: [run.final_force(0).norm(), run.final_force(1).norm()],
            errors,
            dropped_outside_roi: run.dropped_outside_roi,
        }
    }
}

/// The plan of a study.
#[derive(Debug, Clone)]
pub struct Plan {
    /// The reference configuration.
    pub reference: Config,
    /// The grid (baseline first).
    pub grid: Vec<Config>,
    /// Nominal window, s.
    pub window_s: f64,
    /// Force samples per second.
    pub rate_hz: f64,
    /// Deformation interval, s.
    pub dt_s: f64,
    /// Stability sweep.
    pub stability: stability::Sweep,
}

impl Plan {
    /// The full study (paper-48k baseline) or the quick one (coarse).
    pub fn new(quick: bool) -> Self {
        if quick {
            let base = Config {
                preset: "coarse".into(),
                nodes_per_face: 30,
                ..Config::baseline()
            };
            let v = |f: &dyn Fn(&mut Config), sweep: &str| {
                let mut c = base.clone();
                f(&mut c);
                c.sweep = sweep.into();
                c.labelled()
            };
            // The quick reference is the exact linear solution (`direct`):
            // a neo-Hookean reference costs seconds a step in the dev profile.
            let reference = v(&|c| c.strategy = Strategy::Direct, "reference");
            Self {
                reference,
                grid: vec![
                    v(&|_| {}, "baseline"),
                    v(&|c| c.backend = Backend::CpuBrute, "backend"),
                    v(&|c| c.contact_law = ContactLaw::Paper, "contact"),
                ],
                window_s: 1.4,
                rate_hz: 50.0,
                dt_s: 0.1,
                stability: stability::Sweep::quick(),
            }
        } else {
            let base = Config::baseline();
            let v = |f: &dyn Fn(&mut Config), sweep: &str| {
                let mut c = base.clone();
                f(&mut c);
                c.sweep = sweep.into();
                c.labelled()
            };
            let reference = v(
                &|c| {
                    c.strategy = Strategy::NeoHookean;
                    c.tolerance = 1e-9;
                },
                "reference",
            );
            let grid = vec![
                v(&|_| {}, "baseline"),
                v(&|c| c.preset = "coarse".into(), "preset"),
                v(&|c| c.preset = "paper-34k".into(), "preset"),
                v(&|c| c.strategy = Strategy::Corotational, "strategy"),
                v(
                    &|c| {
                        c.strategy = Strategy::Corotational;
                        c.tolerance = 1e-3;
                    },
                    "tolerance",
                ),
                v(
                    &|c| {
                        c.strategy = Strategy::NeoHookean;
                        c.tolerance = 1e-4;
                    },
                    "strategy",
                ),
                v(
                    &|c| {
                        c.strategy = Strategy::NeoHookean;
                        c.tolerance = 1e-6;
                    },
                    "tolerance",
                ),
                v(&|c| c.contact_law = ContactLaw::Paper, "contact"),
                v(&|c| c.nodes_per_face = 30, "nodes-per-face"),
                v(&|c| c.nodes_per_face = 500, "nodes-per-face"),
                v(&|c| c.roi_m = Some(0.03), "roi"),
                v(&|c| c.roi_m = Some(0.045), "roi"),
                v(&|c| c.backend = Backend::CpuBrute, "backend"),
                v(&|c| c.backend = Backend::GpuBvh, "backend"),
                v(&|c| c.threads = 1, "threads"),
                v(
                    &|c| {
                        c.preset = "coarse".into();
                        c.strategy = Strategy::Corotational;
                    },
                    "preset",
                ),
            ];
            Self {
                reference,
                grid,
                window_s: 1.4,
                rate_hz: 200.0,
                dt_s: 0.05,
                stability: stability::Sweep::full(),
            }
        }
    }
}

/// Everything a study produced.
#[derive(Debug, Clone, Serialize)]
pub struct StudyResult {
    /// Reference row.
    pub reference: Option<Row>,
    /// Grid rows.
    pub grid: Vec<Row>,
    /// Stability rows.
    pub stability: Vec<stability::StabilityRow>,
    /// Stability checks.
    pub checks: Vec<stability::Check>,
    /// Total wall time, s.
    pub total_s: f64,
    /// Nominal window, s; force rate, Hz; deformation interval, s.
    pub window_s: f64,
    /// Force samples per second.
    pub rate_hz: f64,
    /// Deformation interval, s.
    pub dt_s: f64,
    /// Whether this was the quick variant.
    pub quick: bool,
}

/// Errors of a study.
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    /// A run could not be set up.
    #[error(transparent)]
    Run(#[from] driver::RunError),
    /// The trajectory could not be loaded.
    #[error(transparent)]
    Trajectory(#[from] crate::trajectory::TrajectoryError),
    /// Writing the outputs.
    #[error("writing {path}: {message}")]
    Output { path: PathBuf, message: String },
}

fn progress(total: u64, hidden: bool) -> ProgressBar {
    if hidden {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(total);
    pb.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:30}] {pos}/{len} steps  eta {eta}  {msg}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    pb
}

/// One line per run on stderr when it is not a terminal (a log, CI), where
/// the progress bar draws nothing: which run starts, and the time so far.
struct RunLog {
    on: bool,
    started: Instant,
    runs: usize,
    done: usize,
}

impl RunLog {
    fn new(hidden: bool, runs: usize, started: Instant) -> Self {
        use std::io::IsTerminal;
        Self {
            on: !hidden && !std::io::stderr().is_terminal(),
            started,
            runs,
            done: 0,
        }
    }

    /// Run `label` starts: the bar's message, and its line.
    fn begin(&mut self, pb: &ProgressBar, label: String) {
        self.done += 1;
        if self.on {
            eprintln!(
                "study: run {}/{}: {label} (at {:.0} s)",
                self.done,
                self.runs,
                self.started.elapsed().as_secs_f64()
            );
        }
        pb.set_message(label);
    }
}

/// Runs the study (without writing anything).
pub fn run_study(args: &StudyArgs) -> Result<StudyResult, StudyError> {
    let started = Instant::now();
    let mut plan = Plan::new(args.quick);
    if let Some(w) = args.window_s {
        plan.window_s = w.clamp(0.05, 2.0);
    }
    if let Some(r) = args.rate_hz {
        plan.rate_hz = r.max(1.0);
    }
    let scenario = Scenario::sylvian(plan.window_s, 1.0, plan.rate_hz, plan.dt_s)?;
    let stab_runs = if args.no_stability {
        Vec::new()
    } else {
        plan.stability.configs(plan.dt_s)
    };
    let grid_steps = if args.no_grid {
        0
    } else {
        (plan.grid.len() + 1) * scenario.steps()
    };
    let stab_steps: usize = stab_runs.iter().map(|(_, s)| s.steps()).sum();
    let pb = progress(
        (grid_steps + stab_steps) as u64,
        args.no_progress || args.json,
    );
    let grid_runs = if args.no_grid { 0 } else { plan.grid.len() + 1 };
    let mut log = RunLog::new(
        args.no_progress || args.json,
        grid_runs + stab_runs.len(),
        started,
    );
    let tick = || pb.inc(1);
    let mut models = ModelCache::default();

    let mut reference_row = None;
    let mut grid = Vec::new();
    let mut plots = Vec::new();
    if !args.no_grid {
        log.begin(&pb, format!("reference {}", plan.reference.label));
        let reference = driver::run(&plan.reference, &scenario, &mut models, true, &tick)?;
        let region = compare::region_vertices(&reference);
        reference_row = Some(Row::of(
            &reference,
            &scenario,
            Some(compare::compare(&reference, &region, &reference)),
        ));
        plots.push((plan.reference.label.clone(), reference.forces_for_plot()));
        for c in &plan.grid {
            log.begin(&pb, c.label.clone());
            let run = driver::run(c, &scenario, &mut models, true, &tick)?;
            let errors = compare::compare(&reference, &region, &run);
            grid.push((
                Row::of(&run, &scenario, Some(errors)),
                run.forces_for_plot(),
            ));
        }
    }
    let mut stab = Vec::new();
    if !args.no_stability {
        for (c, s) in &stab_runs {
            log.begin(&pb, c.label.clone());
            let run = driver::run(c, s, &mut models, false, &tick)?;
            stab.push((Row::of(&run, s, None), run));
        }
    }
    pb.finish_and_clear();
    let (stab_rows, checks) = stability::evaluate(&plan.stability, stab);
    let mut grid_rows = Vec::new();
    for (r, f) in grid {
        plots.push((r.config.label.clone(), f));
        grid_rows.push(r);
    }
    let result = StudyResult {
        reference: reference_row,
        grid: grid_rows,
        stability: stab_rows,
        checks,
        total_s: started.elapsed().as_secs_f64(),
        window_s: plan.window_s,
        rate_hz: plan.rate_hz,
        dt_s: plan.dt_s,
        quick: args.quick,
    };
    output::write_all(&args.out, &result, &plots)?;
    Ok(result)
}

/// `fissure study`: runs, writes the outputs, prints the table (or JSON).
pub fn run(args: &StudyArgs) -> anyhow::Result<()> {
    let result = run_study(args)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&result)?);
    } else {
        println!("{}", output::markdown(&result));
        println!("outputs in {}", args.out.display());
    }
    Ok(())
}
