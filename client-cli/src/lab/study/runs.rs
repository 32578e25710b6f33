//! Computing planned runs: one ([`run_one`]) or a block of them
//! ([`run_range`]), each writing its result file or its failure record.
//!
//! A run whose result file holds it already is skipped unless forced, so an
//! interrupted study, or a job array of which some tasks were cancelled,
//! completes by running again only what is missing. A run that fails (its
//! scene, model or solver cannot be built, or it panics) writes a failure
//! record naming the cause; the other runs of the block go on.

use super::driver::{self, ModelCache};
use super::plan::StudyPlan;
use super::record::{FailureRecord, RunRecord};
use super::{RunLog, StudyError};
use indicatif::ProgressBar;
use std::ops::Range;
use std::path::Path;
use std::time::Instant;

/// What became of a run.
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    /// Computed and written.
    Computed {
        /// Its wall time, s.
        wall_s: f64,
    },
    /// Its result file was there already.
    Skipped,
    /// It failed; the failure record says why.
    Failed(String),
}

fn panic_message(p: &(dyn std::any::Any + Send)) -> String {
    p.downcast_ref::<&str>()
        .map(|s| (*s).to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".into())
}

/// Computes run `index` of `plan` into `dir` (`force`: even when its result
/// is there). `models` caches the built models between the runs of one
/// process; `on_step` is called after each deformation step.
pub fn run_one(
    dir: &Path,
    plan: &StudyPlan,
    index: usize,
    force: bool,
    models: &mut ModelCache,
    on_step: &(dyn Fn() + Sync),
) -> Result<Outcome, StudyError> {
    let run = &plan.runs[index];
    if !force && RunRecord::read(dir, run)?.is_some() {
        return Ok(Outcome::Skipped);
    }
    let started = Instant::now();
    let computed = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        let scenario = run.scenario.scenario_in(&plan.inputs_in(dir))?;
        let result = driver::run(&run.config, &scenario, models, run.keep_surface, on_step)?;
        Ok::<_, StudyError>((scenario.mean_speed_mps, result))
    }));
    let cause = match computed {
        Ok(Ok((speed_mps, result))) => {
            RunRecord {
                id: run.id.clone(),
                scenario: run.scenario,
                speed_mps,
                wall_s: started.elapsed().as_secs_f64(),
                result,
            }
            .write(dir)?;
            return Ok(Outcome::Computed {
                wall_s: started.elapsed().as_secs_f64(),
            });
        }
        Ok(Err(e)) => e.to_string(),
        Err(p) => format!("panicked: {}", panic_message(p.as_ref())),
    };
    FailureRecord {
        id: run.id.clone(),
        cause: cause.clone(),
    }
    .write(dir)?;
    Ok(Outcome::Failed(cause))
}

/// Computes the runs `range` of the plan in `dir`, one after the other,
/// with a progress bar (`hidden`: none, and no log lines). Returns each
/// run's outcome, in order.
pub fn run_range(
    dir: &Path,
    plan: &StudyPlan,
    range: Range<usize>,
    force: bool,
    hidden: bool,
) -> Result<Vec<(usize, Outcome)>, StudyError> {
    let started = Instant::now();
    let pb: ProgressBar = super::progress(plan.steps(range.clone()) as u64, hidden);
    let mut log = RunLog::new(hidden, range.len(), started);
    let tick = || pb.inc(1);
    let mut models = ModelCache::default();
    let mut out = Vec::with_capacity(range.len());
    for i in range {
        let run = &plan.runs[i];
        log.begin(&pb, format!("{} {}", run.id, run.config.label));
        let outcome = run_one(dir, plan, i, force, &mut models, &tick)?;
        log.end(&pb, &run.id, &outcome);
        out.push((i, outcome));
    }
    pb.finish_and_clear();
    Ok(out)
}
