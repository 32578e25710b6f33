//! `fissure study`: speed against accuracy of the simulation's configurations,
//! and stability at the extremes, on a fixed scripted scenario (the bundled
//! Sylvian opening, both spatulas, stepped).
//!
//! * **Grid** (not a full factorial): a baseline, the product's defaults
//!   (paper-48k, linear `compliance`, `tet4`, frictionless contact, the
//!   scene's elastic foundation, 150 source nodes a face, whole brain, CPU
//!   BVH, 2 threads), and sweeps around it: mesh preset, the element (the
//!   locking-free `tet4-nodal-pressure`), every contact law (frictionless,
//!   Coulomb, the paper's projection) under every support (the foundation,
//!   the rigid skull surface, the brain stem alone; [`rules`] compares each
//!   law with its frictionless twin), strategy (`corotational`,
//!   `neo-hookean`, on the foundation; `neo-hookean` also with the
//!   nodal-pressure element, the reference's physics with the nonlinear
//!   law) and tolerance, the nodal-pressure element on paper-48k refined
//!   near the fissure (20 and 30 mm), nodes a face, region of interest,
//!   ray backend, threads. Every run is compared with the **reference**,
//!   paper-48k refined once, below ([`compare`]).
//! * **Convergence of the reference** ([`convergence`]): the reference
//!   physics of the product's scene (frictionless contact, the elastic
//!   foundation, the `tet4-nodal-pressure` element, linear elasticity) on
//!   paper-34k, paper-48k and paper-48k meshed by the proven mesher at 4
//!   (the 204k level), 3.6 and 3.2 mm: force and displacement changes between
//!   levels and a Richardson estimate over the proven family; on the
//!   one-shape families, paper-34k and paper-48k each with its uniform
//!   refinements (`--refinements`, one by default; paper-48k refined once
//!   is the grid's reference, run once); and Poisson's ratio towards
//!   incompressibility on the 204k level with both elements
//!   ([`incompressible`]). The full study plans them (`--convergence-only`:
//!   only them); the quick one does not.
//! * **Stability**: Poisson's ratio, Young's modulus and spatula speed swept
//!   to their extremes ([`stability`]); each run reports whether it stayed
//!   finite, the worst element volume ratio `min det F`, the solver
//!   iterations and its force error, and the checks a user relies on are
//!   evaluated (and asserted by the CI test of `--quick`).
//!
//! The study is a folder: `fissure study plan` writes its runs
//! ([`plan`]), `fissure study run` computes them one by one or in blocks
//! ([`runs`], [`record`]), anywhere (a Slurm job array runs one a task:
//! `client-cli/slurm/study.sbatch`), and `fissure study merge` writes the outputs
//! from the result files ([`merge`]). `fissure study` alone does the three
//! in this process.
//!
//! Cost control (documented in the report): the nominal window is the
//! insertion and the opening (0-1.4 s of the 2 s trajectories), force
//! samples run at `--rate-hz` (200 Hz by default) instead of 1 kHz, and
//! deformation steps every [`Plan::dt_s`] (50 ms, the scene has 20 ms).

pub mod compare;
pub mod config;
pub mod convergence;
pub mod driver;
pub mod haptic;
pub mod incompressible;
pub mod merge;
pub mod output;
pub mod plan;
pub mod record;
pub mod rules;
pub mod runs;
pub mod scenario;
pub mod stability;

use compare::Errors;
use config::{Backend, Config, Support};
use driver::RunResult;
use fissure_engine::fem::{Element, Strategy};
use fissure_engine::scene::ContactLaw;
use indicatif::{ProgressBar, ProgressStyle};
use plan::{PlanOptions, Shard, StudyPlan};
use runs::Outcome;
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// `fissure study`: the whole study in this process, or one of its steps.
#[derive(Debug, Clone, clap::Args)]
#[command(args_conflicts_with_subcommands = true)]
pub struct StudyCommand {
    /// A step of a study run elsewhere (plan, run, merge); none: the whole
    /// study here.
    #[command(subcommand)]
    pub step: Option<StudyStep>,
    /// The whole study in this process.
    #[command(flatten)]
    pub args: StudyArgs,
}

/// The steps of a study computed anywhere (e.g. a Slurm job array).
#[derive(Debug, Clone, clap::Subcommand)]
pub enum StudyStep {
    /// Writes the study's runs into a folder (`DIR/plan.json`).
    Plan(PlanArgs),
    /// Computes runs of a planned folder, each writing `DIR/runs/<id>.cbor`
    /// (or, when it fails, `DIR/runs/<id>.failed.json` naming the cause).
    Run(RunArgs),
    /// Gathers the result files into the study's outputs (grid.csv,
    /// stability.csv, study.md, study.json, plots).
    Merge(MergeArgs),
}

/// Arguments of `fissure study plan`.
#[derive(Debug, Clone, clap::Args)]
pub struct PlanArgs {
    /// The study folder (created).
    #[arg(long)]
    pub out: PathBuf,
    /// What to plan.
    #[command(flatten)]
    pub options: PlanOptions,
}

/// Arguments of `fissure study run`.
#[derive(Debug, Clone, clap::Args)]
pub struct RunArgs {
    /// The study folder (written by `fissure study plan`).
    pub dir: PathBuf,
    /// The run: its id or its index in the plan (a job array's task index).
    #[arg(long, conflicts_with = "shard")]
    pub run: Option<String>,
    /// A block of runs: shard I of N (0-based), e.g. `--shard 2/8`.
    /// Neither `--run` nor `--shard`: every run of the plan.
    #[arg(long)]
    pub shard: Option<Shard>,
    /// Compute the runs even when their result files are there.
    #[arg(long)]
    pub force: bool,
    /// No progress bar and no log lines.
    #[arg(long)]
    pub no_progress: bool,
}

/// Arguments of `fissure study merge`.
#[derive(Debug, Clone, clap::Args)]
pub struct MergeArgs {
    /// The study folder.
    pub dir: PathBuf,
    /// Where the outputs go (default: the study folder).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write the outputs of the runs present even when some are missing or
    /// failed (they are named in study.md and study.json); otherwise the
    /// merge lists them and exits non-zero.
    #[arg(long)]
    pub allow_missing: bool,
    /// Print the rows as JSON on stdout.
    #[arg(long)]
    pub json: bool,
}

/// Arguments of `fissure study` (the whole study in this process).
#[derive(Debug, Clone, clap::Args)]
pub struct StudyArgs {
    /// Output folder (the plan, the result files, CSV, markdown, PNG plots).
    #[arg(long, default_value = "fissure-out/study")]
    pub out: PathBuf,
    /// What to run.
    #[command(flatten)]
    pub options: PlanOptions,
    /// Keep the runs already computed in the output folder for this plan
    /// (continue an interrupted study) instead of computing them again.
    #[arg(long)]
    pub resume: bool,
    /// Print the rows as JSON on stdout.
    #[arg(long)]
    pub json: bool,
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
    /// The force samples against the steps at the same instants
    /// ([`haptic`]); `None` where nothing pushes.
    pub haptic: Option<haptic::HapticError>,
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
    /// The row of a run whose scenario's mean handle speed is `speed_mps`.
    pub fn of(run: &RunResult, speed_mps: f64, errors: Option<Errors>) -> Self {
        Self {
            config: run.config.clone(),
            backend_used: run.backend_used.clone(),
            speed_mps,
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
            haptic: run.haptic_error(),
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
    /// The reference physics on successively finer meshes, coarsest first
    /// ([`convergence`]).
    pub convergence: Vec<Config>,
    /// The product's meshes refined uniformly, the one-shape families
    /// ([`convergence::refined`]).
    pub refined: Vec<Config>,
    /// Poisson's ratio towards incompressibility on the 204k level, both
    /// elements ([`incompressible`]).
    pub incompressible: Vec<Config>,
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
                // The levels' meshes (up to 204k tetrahedra) cost seconds a
                // step in the dev profile the CI test runs: the quick study
                // has no convergence part (its arithmetic is a unit test of
                // [`convergence`]).
                convergence: Vec::new(),
                refined: Vec::new(),
                incompressible: Vec::new(),
            }
        } else {
            let levels = convergence::levels(&Config::baseline());
            // The product's configuration, held as the bundled scene holds
            // the brain (the foundation).
            let base = Config {
                support: Support::Foundation,
                ..Config::baseline()
            };
            let v = |f: &dyn Fn(&mut Config), sweep: &str| {
                let mut c = base.clone();
                f(&mut c);
                c.sweep = sweep.into();
                c.labelled()
            };
            // The product's shape refined: one of the one-shape levels,
            // run once as the reference.
            let reference = convergence::reference(&Config::baseline());
            let mut grid = vec![
                v(&|_| {}, "baseline"),
                v(&|c| c.preset = "coarse".into(), "preset"),
                v(&|c| c.preset = "paper-34k".into(), "preset"),
                v(&|c| c.element = Element::Tet4NodalPressure, "element"),
            ];
            // Contact rule x support: every law under every support (the
            // baseline is frictionless on the foundation).
            for support in Support::ALL {
                for law in ContactLaw::ALL {
                    if support == Support::Foundation && law == ContactLaw::Frictionless {
                        continue;
                    }
                    grid.push(v(
                        &|c| {
                            c.support = support;
                            c.contact_law = law;
                            c.friction_coefficient =
                                (law == ContactLaw::Coulomb).then_some(COULOMB_MU);
                        },
                        "contact-support",
                    ));
                }
            }
            grid.extend([
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
                        c.tolerance = 1e-6;
                    },
                    "strategy",
                ),
                // The reference's element and support with the nonlinear
                // law: beside the `element` run, the material law's share
                // of the error at this mesh.
                v(
                    &|c| {
                        c.strategy = Strategy::NeoHookean;
                        c.element = Element::Tet4NodalPressure;
                        c.tolerance = 1e-6;
                    },
                    "strategy",
                ),
                // The nodal-pressure element on paper-48k refined once
                // within 20 and 30 mm of the fissure centre (the rest of
                // the mesh as it is): the reference's resolution where the
                // plates press, at a fraction of its cost.
                v(
                    &|c| {
                        c.element = Element::Tet4NodalPressure;
                        c.refine_near_m = vec![0.02];
                    },
                    "refine-near",
                ),
                v(
                    &|c| {
                        c.element = Element::Tet4NodalPressure;
                        c.refine_near_m = vec![0.03];
                    },
                    "refine-near",
                ),
                v(&|c| c.nodes_per_face = 30, "nodes-per-face"),
                v(&|c| c.nodes_per_face = 500, "nodes-per-face"),
                v(&|c| c.roi_m = Some(0.03), "roi"),
                v(&|c| c.roi_m = Some(0.045), "roi"),
                v(&|c| c.backend = Backend::CpuBrute, "backend"),
                v(&|c| c.backend = Backend::GpuBvh, "backend"),
                v(&|c| c.threads = 1, "threads"),
            ]);
            Self {
                reference,
                grid,
                window_s: 1.4,
                rate_hz: 200.0,
                dt_s: 0.05,
                stability: stability::Sweep::full(),
                incompressible: incompressible::configs(&levels, convergence::SWEEP_LEVEL),
                refined: convergence::refined(
                    &Config::baseline(),
                    convergence::DEFAULT_REFINEMENTS,
                ),
                convergence: levels,
            }
        }
    }

    /// Whether the level `c` (a convergence level or a refinement) is the
    /// reference (the full study's paper-48k refined once): it is then run
    /// once, as the reference, and takes its place among the levels.
    pub fn is_reference(&self, c: &Config) -> bool {
        Config {
            sweep: self.reference.sweep.clone(),
            ..c.clone()
        } == self.reference
    }

    /// Whether the reference is one of the levels (a convergence level or
    /// a refinement): one run then serves both.
    pub fn reference_is_a_level(&self) -> bool {
        self.convergence
            .iter()
            .chain(&self.refined)
            .any(|c| self.is_reference(c))
    }
}

/// Coulomb's friction coefficient of the study's `coulomb` runs: an assumed
/// value for a wet steel spatula on the pia (a sensitivity case, not a
/// measured one).
pub const COULOMB_MU: f64 = 0.2;

/// Everything a study produced.
#[derive(Debug, Clone, Serialize)]
pub struct StudyResult {
    /// Reference row.
    pub reference: Option<Row>,
    /// Grid rows.
    pub grid: Vec<Row>,
    /// The contact laws beside their frictionless twins ([`rules`]).
    pub contact_rules: Vec<rules::RuleRow>,
    /// Stability rows.
    pub stability: Vec<stability::StabilityRow>,
    /// Stability checks.
    pub checks: Vec<stability::Check>,
    /// Convergence of the reference over the mesh levels (two levels at
    /// least).
    pub convergence: Option<convergence::Convergence>,
    /// Poisson's ratio towards incompressibility on the 204k level.
    pub incompressible: Option<incompressible::Incompressible>,
    /// Wall time of the runs, s (their sum, wherever they ran).
    pub total_s: f64,
    /// Nominal window, s; force rate, Hz; deformation interval, s.
    pub window_s: f64,
    /// Force samples per second.
    pub rate_hz: f64,
    /// Deformation interval, s.
    pub dt_s: f64,
    /// Whether this was the quick variant.
    pub quick: bool,
    /// Runs of the plan without a result (merged with `--allow-missing`).
    pub absent: Vec<merge::Absent>,
}

/// Errors of a study.
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    /// A run could not be set up.
    #[error(transparent)]
    Run(#[from] driver::RunError),
    /// The trajectory could not be loaded.
    #[error(transparent)]
    Trajectory(#[from] crate::client::trajectory::TrajectoryError),
    /// Writing the outputs.
    #[error("writing {path}: {message}")]
    Output { path: PathBuf, message: String },
    /// The plan file is missing, unreadable or of another version.
    #[error("study plan {path}: {message}")]
    Plan { path: PathBuf, message: String },
    /// A result file or failure record is unreadable or not the plan's.
    #[error("run file {path}: {message}")]
    Record { path: PathBuf, message: String },
    /// `--run` names no run of the plan.
    #[error(
        "no run {key:?} in the plan ({runs} runs: give an id from plan.json or an index below {runs})"
    )]
    UnknownRun { key: String, runs: usize },
    /// Runs failed.
    #[error("{} of {runs} runs failed: {}", failed.len(), failed.iter().map(|(id, c)| format!("{id}: {c}")).collect::<Vec<_>>().join("; "))]
    Failed {
        runs: usize,
        failed: Vec<(String, String)>,
    },
    /// The merge found runs without a result.
    #[error("{dir}: {} of {runs} runs have no result: {}", absent.len(), describe_absent(absent))]
    Incomplete {
        dir: PathBuf,
        runs: usize,
        absent: Vec<merge::Absent>,
    },
}

fn describe_absent(absent: &[merge::Absent]) -> String {
    let list: Vec<String> = absent
        .iter()
        .map(|a| match &a.failure {
            Some(c) => format!("{} (index {}, failed: {c})", a.id, a.index),
            None => format!("{} (index {}, missing)", a.id, a.index),
        })
        .collect();
    let indices: Vec<String> = absent.iter().map(|a| a.index.to_string()).collect();
    format!(
        "{}; compute them (`fissure study run DIR --run ID`, or on Slurm `sbatch --array={} client-cli/slurm/study.sbatch DIR`) or merge with --allow-missing",
        list.join(", "),
        indices.join(",")
    )
}

pub(crate) fn progress(total: u64, hidden: bool) -> ProgressBar {
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
pub(crate) struct RunLog {
    on: bool,
    started: Instant,
    runs: usize,
    done: usize,
}

impl RunLog {
    pub(crate) fn new(hidden: bool, runs: usize, started: Instant) -> Self {
        use std::io::IsTerminal;
        Self {
            on: !hidden && !std::io::stderr().is_terminal(),
            started,
            runs,
            done: 0,
        }
    }

    /// Run `label` starts: the bar's message, and its line.
    pub(crate) fn begin(&mut self, pb: &ProgressBar, label: String) {
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

impl RunLog {
    /// Run `id` ended: a line when it did not compute (skipped, failed).
    pub(crate) fn end(&mut self, pb: &ProgressBar, id: &str, outcome: &Outcome) {
        let line = match outcome {
            Outcome::Computed { .. } => return,
            Outcome::Skipped => {
                format!("study: {id}: its result is there already (--force computes it again)")
            }
            Outcome::Failed(cause) => format!("study: {id} FAILED: {cause}"),
        };
        if self.on {
            eprintln!("{line}");
        } else {
            pb.println(line);
        }
    }
}

/// Runs the whole study in this process: plans it into `args.out`,
/// computes every run there and merges the result files into the outputs.
pub fn run_study(args: &StudyArgs) -> Result<StudyResult, StudyError> {
    let plan = StudyPlan::new(&args.options)?.write(&args.out)?;
    let hidden = args.no_progress || args.json;
    let outcomes = runs::run_range(&args.out, &plan, 0..plan.runs.len(), !args.resume, hidden)?;
    let failed: Vec<(String, String)> = outcomes
        .into_iter()
        .filter_map(|(i, o)| match o {
            Outcome::Failed(cause) => Some((plan.runs[i].id.clone(), cause)),
            _ => None,
        })
        .collect();
    if !failed.is_empty() {
        return Err(StudyError::Failed {
            runs: plan.runs.len(),
            failed,
        });
    }
    merge::merge(&args.out, &args.out, false)
}

fn print_result(result: &StudyResult, json: bool, out: &Path) -> anyhow::Result<()> {
    if json {
        println!("{}", serde_json::to_string_pretty(result)?);
    } else {
        println!("{}", output::markdown(result));
        println!("outputs in {}", out.display());
    }
    Ok(())
}

/// `fissure study`: the whole study, or `plan`, `run` or `merge`.
pub fn command(cmd: &StudyCommand) -> anyhow::Result<()> {
    match &cmd.step {
        None => {
            let result = run_study(&cmd.args)?;
            print_result(&result, cmd.args.json, &cmd.args.out)
        }
        Some(StudyStep::Plan(a)) => {
            let plan = StudyPlan::new(&a.options)?.write(&a.out)?;
            let dir = a.out.display();
            let threads = plan
                .runs
                .iter()
                .map(|r| r.config.threads)
                .max()
                .unwrap_or(1);
            println!(
                "{} runs planned in {}",
                plan.runs.len(),
                StudyPlan::path(&a.out).display()
            );
            for (i, r) in plan.runs.iter().enumerate() {
                println!("  {i:>3}  {}", r.id);
            }
            println!(
                "compute them here:  fissure study run {dir}\n\
                 or on Slurm:        sbatch --array=0-{} --cpus-per-task={threads} client-cli/slurm/study.sbatch {dir}\n\
                 then:               fissure study merge {dir}",
                plan.runs.len().saturating_sub(1)
            );
            Ok(())
        }
        Some(StudyStep::Run(a)) => {
            let plan = StudyPlan::read(&a.dir)?;
            let range = match (&a.run, a.shard) {
                (Some(key), _) => {
                    let i = plan.find(key)?;
                    i..i + 1
                }
                (None, Some(s)) => plan.shard(s.index, s.count),
                (None, None) => 0..plan.runs.len(),
            };
            let outcomes = runs::run_range(&a.dir, &plan, range, a.force, a.no_progress)?;
            let mut failed = Vec::new();
            for (i, o) in outcomes {
                let id = &plan.runs[i].id;
                match o {
                    Outcome::Computed { wall_s } => println!("{id}: computed in {wall_s:.1} s"),
                    Outcome::Skipped => println!("{id}: done already"),
                    Outcome::Failed(cause) => failed.push((id.clone(), cause)),
                }
            }
            if failed.is_empty() {
                Ok(())
            } else {
                Err(StudyError::Failed {
                    runs: plan.runs.len(),
                    failed,
                }
                .into())
            }
        }
        Some(StudyStep::Merge(a)) => {
            let out = a.out.clone().unwrap_or_else(|| a.dir.clone());
            let result = merge::merge(&a.dir, &out, a.allow_missing)?;
            if !result.absent.is_empty() {
                eprintln!(
                    "study merge: {} runs have no result and are left out: {}",
                    result.absent.len(),
                    describe_absent(&result.absent)
                );
            }
            print_result(&result, a.json, &out)
        }
    }
}
