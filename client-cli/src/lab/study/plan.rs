//! The study as a list of independent runs, written to a folder so that the
//! runs can be computed anywhere (this process, a shell loop, a Slurm job
//! array) and merged afterwards.
//!
//! `DIR/plan.json` holds the plan: what the study is (quick or full, the
//! window, the force rate, the deformation interval) and its runs, each an
//! id, a role (the reference, a grid run, a stability run), the
//! configuration and the scenario it plays. The id starts with the run's
//! index, zero-padded (`03-coarse_lin_n30_cpu-brute`), so that a job
//! array's task index names its run. The shared inputs are written beside
//! it (`DIR/inputs/`: the scene the configurations edit and the two
//! trajectories) and every run reads them from there; the phantom presets
//! are the `fissure`'s own, so the plan records its version, and a `fissure`
//! of another version refuses to run or merge it.
//!
//! Runs read their configuration from the file, never from the code that
//! planned it, so a run computed in this process and one computed by a job
//! array solve the same problem bit for bit.

use super::config::Config;
use super::scenario::{Inputs, ScenarioSpec};
use super::{Plan, StudyError};
use serde::{Deserialize, Serialize};
use std::ops::Range;
use std::path::{Path, PathBuf};

/// The plan file of a study folder.
pub const PLAN_FILE: &str = "plan.json";
/// The folder of the shared inputs, inside a study folder.
pub const INPUTS_DIR: &str = "inputs";
/// The plan file's format tag.
pub const PLAN_FORMAT: &str = "fissure-study-plan/1";
/// The bundled scene the study's configurations edit.
const SCENE: &str = "sylvian";

/// What a run is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Role {
    /// The run every grid run is compared with.
    Reference,
    /// A run of the speed-accuracy grid.
    Grid,
    /// A run of the stability sweep.
    Stability,
    /// A level of the reference's mesh convergence.
    Convergence,
    /// A product mesh refined uniformly: one shape, a finer `h`.
    Refined,
    /// A run of the Poisson's ratio sweep towards incompressibility on the
    /// 204k level.
    Incompressible,
}

/// One run of the plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlannedRun {
    /// Unique id: the index, zero-padded, and the label made file-name-safe.
    pub id: String,
    /// What the run is for.
    pub role: Role,
    /// Its configuration.
    pub config: Config,
    /// The scenario it plays.
    pub scenario: ScenarioSpec,
    /// Whether every step's surface displacements are kept (for the
    /// comparison with the reference).
    pub keep_surface: bool,
}

/// The plan of a study folder.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StudyPlan {
    /// [`PLAN_FORMAT`].
    pub format: String,
    /// Version of the `fissure` that wrote it.
    pub fissure_version: String,
    /// The quick variant.
    pub quick: bool,
    /// Nominal window of the grid runs, s.
    pub window_s: f64,
    /// Force samples per second of the grid runs.
    pub rate_hz: f64,
    /// Deformation interval, s.
    pub dt_s: f64,
    /// The shared inputs every run reads, relative to the study folder.
    pub inputs: Inputs,
    /// The runs, in order: the reference and the grid, the convergence
    /// levels (coarsest first) and the incompressibility sweep, then the
    /// stability sweep.
    pub runs: Vec<PlannedRun>,
}

/// What to plan.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct PlanOptions {
    /// The cheap variant: coarse preset only, short window (CI runs it).
    #[arg(long)]
    pub quick: bool,
    /// Force-loop samples per second of simulated time (default 200, quick 50).
    #[arg(long)]
    pub rate_hz: Option<f64>,
    /// Nominal window of the trajectory played, s (at most 2; default 1.4).
    #[arg(long)]
    pub window_s: Option<f64>,
    /// Skip the speed-accuracy grid.
    #[arg(long)]
    pub no_grid: bool,
    /// Skip the stability sweep.
    #[arg(long)]
    pub no_stability: bool,
    /// Skip the convergence of the reference over the mesh levels (the
    /// reference is still run for the grid) and the incompressibility sweep
    /// on the 204k level.
    #[arg(long)]
    pub no_convergence: bool,
    /// Only the convergence of the reference over the mesh levels and the
    /// incompressibility sweep on the 204k level (no grid, no stability
    /// sweep).
    #[arg(long, conflicts_with = "no_convergence")]
    pub convergence_only: bool,
    /// Uniform refinements of paper-34k and paper-48k in the convergence
    /// part (each splits every tetrahedron into eight; default 1, which
    /// the reference needs: paper-48k refined once peaks at 16 GB; 2 adds
    /// 2.2 M and 3.2 M tetrahedra, for a machine of well over 100 GB).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=fissure_engine::mesh::refine::MAX_REFINEMENTS as i64))]
    pub refinements: Option<u32>,
}

fn io_err(path: &Path, e: impl std::fmt::Display) -> StudyError {
    StudyError::Output {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

impl StudyPlan {
    /// The plan `options` ask for.
    pub fn new(options: &PlanOptions) -> Result<Self, StudyError> {
        let mut plan = Plan::new(options.quick);
        if let Some(w) = options.window_s {
            plan.window_s = w.clamp(0.05, 2.0);
        }
        if let Some(r) = options.rate_hz {
            plan.rate_hz = r.max(1.0);
        }
        let grid_spec = ScenarioSpec {
            window_s: plan.window_s,
            time_scale: 1.0,
            rate_hz: plan.rate_hz,
            dt_s: plan.dt_s,
        };
        if let (Some(n), false) = (options.refinements, plan.refined.is_empty()) {
            plan.refined = super::convergence::refined(&Config::baseline(), n);
        }
        let mut runs: Vec<(Role, Config, ScenarioSpec, bool)> = Vec::new();
        let grid = !options.no_grid && !options.convergence_only;
        let convergence = !options.no_convergence && !plan.convergence.is_empty();
        if grid || (convergence && plan.reference_is_a_level()) {
            runs.push((Role::Reference, plan.reference.clone(), grid_spec, true));
        }
        if grid {
            runs.extend(
                plan.grid
                    .iter()
                    .map(|c| (Role::Grid, c.clone(), grid_spec, true)),
            );
        }
        if convergence {
            runs.extend(
                plan.convergence
                    .iter()
                    .filter(|c| !plan.is_reference(c))
                    .map(|c| (Role::Convergence, c.clone(), grid_spec, true)),
            );
            runs.extend(
                plan.refined
                    .iter()
                    .filter(|c| !plan.is_reference(c))
                    .map(|c| (Role::Refined, c.clone(), grid_spec, true)),
            );
            runs.extend(
                plan.incompressible
                    .iter()
                    .map(|c| (Role::Incompressible, c.clone(), grid_spec, false)),
            );
        }
        if !options.no_stability && !options.convergence_only {
            for (c, s) in plan.stability.configs(plan.dt_s)? {
                runs.push((Role::Stability, c, s, false));
            }
        }
        let width = runs.len().saturating_sub(1).to_string().len().max(2);
        let bundled = Inputs::bundled();
        Ok(Self {
            format: PLAN_FORMAT.into(),
            fissure_version: env!("CARGO_PKG_VERSION").into(),
            quick: options.quick,
            window_s: plan.window_s,
            rate_hz: plan.rate_hz,
            dt_s: plan.dt_s,
            inputs: Inputs {
                scene: format!("{INPUTS_DIR}/{SCENE}.toml"),
                left: format!("{INPUTS_DIR}/{}.csv", bundled.left),
                right: format!("{INPUTS_DIR}/{}.csv", bundled.right),
            },
            runs: runs
                .into_iter()
                .enumerate()
                .map(|(i, (role, config, scenario, keep_surface))| PlannedRun {
                    id: format!("{i:0width$}-{}", super::output::slug(&config.label)),
                    role,
                    config,
                    scenario,
                    keep_surface,
                })
                .collect(),
        })
    }

    /// The plan file of `dir`.
    pub fn path(dir: &Path) -> PathBuf {
        dir.join(PLAN_FILE)
    }

    /// Writes the plan and the shared inputs (the bundled scene and
    /// trajectories the runs read) into `dir` (created), and reads the plan
    /// back: what the runs compute is what the files say.
    pub fn write(&self, dir: &Path) -> Result<Self, StudyError> {
        std::fs::create_dir_all(dir.join(super::record::RUNS_DIR)).map_err(|e| io_err(dir, e))?;
        std::fs::create_dir_all(dir.join(INPUTS_DIR)).map_err(|e| io_err(dir, e))?;
        let bundled = Inputs::bundled();
        let scene = fissure_engine::scene::EMBEDDED
            .iter()
            .find(|(n, _)| *n == SCENE)
            .map(|(_, text)| *text)
            .expect("the study's scene is bundled");
        super::record::write_atomically(&dir.join(&self.inputs.scene), scene.as_bytes())?;
        for (name, file) in [
            (&bundled.left, &self.inputs.left),
            (&bundled.right, &self.inputs.right),
        ] {
            let text = crate::client::trajectory::BUNDLED
                .iter()
                .find(|b| b.0 == name.as_str())
                .map(|b| b.3)
                .expect("the study's trajectories are bundled");
            super::record::write_atomically(&dir.join(file), text.as_bytes())?;
        }
        let path = Self::path(dir);
        let json = serde_json::to_string_pretty(self).map_err(|e| io_err(&path, e))?;
        super::record::write_atomically(&path, json.as_bytes())?;
        Self::read(dir)
    }

    /// Reads the plan of `dir`, refusing one of another format or version.
    pub fn read(dir: &Path) -> Result<Self, StudyError> {
        let path = Self::path(dir);
        let text = std::fs::read_to_string(&path).map_err(|e| StudyError::Plan {
            path: path.clone(),
            message: format!(
                "{e} (write one with `fissure study plan --out {}`)",
                dir.display()
            ),
        })?;
        let plan: Self = serde_json::from_str(&text).map_err(|e| StudyError::Plan {
            path: path.clone(),
            message: e.to_string(),
        })?;
        if plan.format != PLAN_FORMAT {
            return Err(StudyError::Plan {
                path,
                message: format!(
                    "format {:?}, this fissure reads {PLAN_FORMAT:?}",
                    plan.format
                ),
            });
        }
        let mine = env!("CARGO_PKG_VERSION");
        if plan.fissure_version != mine {
            return Err(StudyError::Plan {
                path,
                message: format!(
                    "written by fissure {}, this is {mine}: the bundled inputs may differ; plan again",
                    plan.fissure_version
                ),
            });
        }
        Ok(plan)
    }

    /// The shared inputs, as paths under `dir`.
    pub fn inputs_in(&self, dir: &Path) -> Inputs {
        let under = |f: &str| dir.join(f).display().to_string();
        Inputs {
            scene: under(&self.inputs.scene),
            left: under(&self.inputs.left),
            right: under(&self.inputs.right),
        }
    }

    /// The index of the run named `key`: its id, or its index.
    pub fn find(&self, key: &str) -> Result<usize, StudyError> {
        if let Some(i) = self.runs.iter().position(|r| r.id == key) {
            return Ok(i);
        }
        match key.parse::<usize>() {
            Ok(i) if i < self.runs.len() => Ok(i),
            _ => Err(StudyError::UnknownRun {
                key: key.into(),
                runs: self.runs.len(),
            }),
        }
    }

    /// The runs of shard `index` of `count` (contiguous blocks whose sizes
    /// differ by at most one).
    pub fn shard(&self, index: usize, count: usize) -> Range<usize> {
        let n = self.runs.len();
        let count = count.max(1);
        (index * n / count)..((index + 1) * n / count)
    }

    /// Deformation steps of the runs in `range` (for a progress bar).
    pub fn steps(&self, range: Range<usize>) -> usize {
        self.runs[range].iter().map(|r| r.scenario.steps()).sum()
    }
}

/// A shard `I/N` (`0 <= I < N`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    /// Which shard.
    pub index: usize,
    /// Of how many.
    pub count: usize,
}

impl std::str::FromStr for Shard {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let (i, n) = s
            .split_once('/')
            .ok_or_else(|| format!("{s:?}: a shard is I/N, e.g. 0/4"))?;
        let index: usize = i
            .trim()
            .parse()
            .map_err(|e| format!("{s:?}: shard index {i:?}: {e}"))?;
        let count: usize = n
            .trim()
            .parse()
            .map_err(|e| format!("{s:?}: shard count {n:?}: {e}"))?;
        if count == 0 || index >= count {
            return Err(format!(
                "{s:?}: the index must be below the count (0/{n} to {}/{n})",
                count.saturating_sub(1)
            ));
        }
        Ok(Self { index, count })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_cover_every_run_once_in_blocks() {
        let plan = StudyPlan::new(&PlanOptions {
            quick: true,
            ..PlanOptions::default()
        })
        .expect("the quick plan");
        for count in 1..=plan.runs.len() + 2 {
            let mut seen = Vec::new();
            for index in 0..count {
                let r = plan.shard(index, count);
                assert!(r.len() <= plan.runs.len() / count + 1);
                seen.extend(r);
            }
            assert_eq!(
                seen,
                (0..plan.runs.len()).collect::<Vec<_>>(),
                "{count} shards"
            );
        }
    }

    #[test]
    fn a_run_is_found_by_id_or_index_and_an_unknown_one_is_named() {
        let plan = StudyPlan::new(&PlanOptions {
            quick: true,
            ..PlanOptions::default()
        })
        .expect("the quick plan");
        assert_eq!(plan.runs[0].role, Role::Reference);
        let last = plan.runs.len() - 1;
        assert_eq!(plan.find(&plan.runs[last].id).unwrap(), last);
        assert_eq!(plan.find(&last.to_string()).unwrap(), last);
        let e = plan.find("99-nothing").unwrap_err().to_string();
        assert!(e.contains("99-nothing"), "{e}");
        let e = plan
            .find(&plan.runs.len().to_string())
            .unwrap_err()
            .to_string();
        assert!(e.contains(&format!("{} runs", plan.runs.len())), "{e}");
        // Ids are unique and start with their index.
        for (i, r) in plan.runs.iter().enumerate() {
            assert!(r.id.starts_with(&format!("{i:02}-")), "{}", r.id);
            assert_eq!(plan.runs.iter().filter(|o| o.id == r.id).count(), 1);
        }
    }

    #[test]
    fn the_full_reference_is_paper_48k_refined_once_planned_once_whatever_part_is_asked() {
        let planned = Plan::new(false);
        let level = planned
            .refined
            .iter()
            .find(|c| planned.is_reference(c))
            .expect("the reference is a one-shape level")
            .clone();
        assert_eq!(level.label, "48k-r1/lin/n150/np/foundation");
        assert_eq!(level.refine, 1);
        let count =
            |plan: &StudyPlan, role: Role| plan.runs.iter().filter(|r| r.role == role).count();
        let refined = |plan: &StudyPlan| -> Vec<String> {
            plan.runs
                .iter()
                .filter(|r| r.role == Role::Refined)
                .map(|r| r.config.label.clone())
                .collect()
        };
        for (options, grid) in [
            (PlanOptions::default(), true),
            (
                PlanOptions {
                    convergence_only: true,
                    ..PlanOptions::default()
                },
                false,
            ),
        ] {
            let plan = StudyPlan::new(&options).expect("the full plan");
            assert_eq!(plan.runs[0].role, Role::Reference);
            assert_eq!(count(&plan, Role::Reference), 1);
            let reference = &plan.runs[0].config;
            assert_eq!(reference.label, level.label);
            assert_eq!(reference.sweep, "reference");
            // Every mesher level is planned; the reference's one-shape level
            // is not planned again: paper-34k refined once is the other.
            assert_eq!(count(&plan, Role::Convergence), planned.convergence.len());
            assert_eq!(refined(&plan), ["34k-r1/lin/n150/np/foundation"]);
            assert_eq!(count(&plan, Role::Grid) > 0, grid);
        }
        // Two refinements add both families' second level, the reference
        // still planned once.
        let plan = StudyPlan::new(&PlanOptions {
            convergence_only: true,
            refinements: Some(2),
            ..PlanOptions::default()
        })
        .expect("two refinements");
        assert_eq!(
            refined(&plan),
            [
                "34k-r1/lin/n150/np/foundation",
                "34k-r2/lin/n150/np/foundation",
                "48k-r2/lin/n150/np/foundation"
            ]
        );
        assert_eq!(count(&plan, Role::Reference), 1);
        // Without the convergence part the reference is still planned for
        // the grid; without the grid nor the convergence, it is not.
        let plan = StudyPlan::new(&PlanOptions {
            no_convergence: true,
            ..PlanOptions::default()
        })
        .expect("the grid alone");
        assert_eq!(count(&plan, Role::Reference), 1);
        assert_eq!(count(&plan, Role::Convergence), 0);
        let plan = StudyPlan::new(&PlanOptions {
            no_convergence: true,
            no_grid: true,
            ..PlanOptions::default()
        })
        .expect("the stability sweep alone");
        assert_eq!(count(&plan, Role::Reference), 0);
    }

    #[test]
    fn the_full_grid_crosses_every_contact_law_with_every_support() {
        use super::super::config::Support;
        use fissure_engine::scene::ContactLaw;
        let plan = Plan::new(false);
        for support in Support::ALL {
            for law in ContactLaw::ALL {
                let runs: Vec<_> = plan
                    .grid
                    .iter()
                    .filter(|c| {
                        c.support == support
                            && c.contact_law == law
                            && c.preset == "paper-48k"
                            && c.strategy == fissure_engine::fem::Strategy::Compliance
                            && c.element == fissure_engine::fem::Element::Tet4
                            && c.nodes_per_face == 150
                            && c.roi_m.is_none()
                            && c.backend == super::super::config::Backend::CpuBvh
                            && c.threads == 2
                    })
                    .collect();
                assert_eq!(runs.len(), 1, "{support:?} x {law:?}");
                assert_eq!(
                    runs[0].friction_coefficient.is_some(),
                    law == ContactLaw::Coulomb
                );
                runs[0].scene().expect("a valid scene");
            }
        }
        let labels: Vec<_> = plan.grid.iter().map(|c| &c.label).collect();
        for (i, l) in labels.iter().enumerate() {
            assert!(!labels[..i].contains(l), "{l} twice");
        }
    }

    #[test]
    fn shards_are_parsed_and_bad_ones_refused_with_the_reason() {
        assert_eq!(
            "2/5".parse::<Shard>().unwrap(),
            Shard { index: 2, count: 5 }
        );
        for bad in ["5/5", "1/0", "a/2", "3", "-1/2"] {
            let e = bad.parse::<Shard>().unwrap_err();
            assert!(e.contains(bad), "{bad}: {e}");
        }
    }

    #[test]
    fn a_plan_reads_back_as_written_and_another_version_is_refused() {
        let dir = tempfile::tempdir().expect("temporary folder");
        let plan = StudyPlan::new(&PlanOptions {
            quick: true,
            ..PlanOptions::default()
        })
        .expect("the quick plan");
        let back = plan.write(dir.path()).expect("written");
        assert_eq!(back.runs.len(), plan.runs.len());
        // The shared inputs are there and read as the bundled ones.
        let inputs = back.inputs_in(dir.path());
        let (scene, _) = fissure_engine::scene::Scene::load(&inputs.scene).expect("the scene");
        assert_eq!(
            scene,
            fissure_engine::scene::Scene::load("sylvian").unwrap().0
        );
        let spec = back.runs[0].scenario;
        let (a, b) = (
            spec.scenario_in(&inputs).expect("the trajectories"),
            spec.scenario().expect("the bundled ones"),
        );
        assert_eq!((a.times, a.end_s), (b.times, b.end_s));
        for (x, y) in a.tracks.iter().zip(&b.tracks) {
            assert_eq!(x.poses, y.poses, "{}", x.instrument);
        }
        assert_eq!(back, StudyPlan::read(dir.path()).expect("read"));
        let mut old = back.clone();
        old.fissure_version = "0.0.1".into();
        std::fs::write(
            StudyPlan::path(dir.path()),
            serde_json::to_string(&old).unwrap(),
        )
        .unwrap();
        let e = StudyPlan::read(dir.path()).unwrap_err().to_string();
        assert!(e.contains("0.0.1") && e.contains("plan again"), "{e}");
        let e = StudyPlan::read(&dir.path().join("none"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("fissure study plan"), "{e}");
    }
}
