//! Gathering a study folder's result files into the study's outputs.
//!
//! The merge reads the plan and each run's result file, compares every grid
//! run with the reference ([`compare`](super::compare)), evaluates the
//! stability sweep ([`stability::evaluate`](super::stability::evaluate)) and
//! writes `grid.csv`, `stability.csv`, `study.md`, `study.json` and the
//! plots ([`output`](super::output)). It is the only path to the outputs:
//! `fissure study` in one process plans, runs and merges, so a study
//! computed by a Slurm job array and one computed in one process give the
//! same files (every value but the measured times, which are the
//! machine's).
//!
//! Runs whose result is missing or that failed are listed; the merge
//! refuses to write outputs from an incomplete folder unless asked to
//! (`allow_missing`), and then writes what the present runs give and names
//! the absent ones in `study.md` and `study.json`.

use super::plan::{Role, StudyPlan};
use super::record::{FailureRecord, RunRecord};
use super::{
    Plan, Row, StudyError, StudyResult, compare, convergence, incompressible, output, rules,
    stability,
};
use serde::Serialize;
use std::path::Path;

/// A run the merge did not find a result for.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Absent {
    /// The run's id.
    pub id: String,
    /// Its index in the plan (a job array's task index).
    pub index: usize,
    /// Why it failed, when it wrote a failure record; `None`: no result yet.
    pub failure: Option<String>,
}

/// The absent runs of the plan in `dir`, and the present ones' records.
pub fn gather(
    dir: &Path,
    plan: &StudyPlan,
) -> Result<(Vec<Option<RunRecord>>, Vec<Absent>), StudyError> {
    let mut records = Vec::with_capacity(plan.runs.len());
    let mut absent = Vec::new();
    for (index, run) in plan.runs.iter().enumerate() {
        let rec = RunRecord::read(dir, run)?;
        if rec.is_none() {
            absent.push(Absent {
                id: run.id.clone(),
                index,
                failure: FailureRecord::read(dir, &run.id)?.map(|f| f.cause),
            });
        }
        records.push(rec);
    }
    Ok((records, absent))
}

/// Merges the study folder `dir` into outputs in `out`.
pub fn merge(dir: &Path, out: &Path, allow_missing: bool) -> Result<StudyResult, StudyError> {
    let plan = StudyPlan::read(dir)?;
    let (records, absent) = gather(dir, &plan)?;
    if !absent.is_empty() && !allow_missing {
        return Err(StudyError::Incomplete {
            dir: dir.to_path_buf(),
            absent,
            runs: plan.runs.len(),
        });
    }
    let reference = plan
        .runs
        .iter()
        .zip(&records)
        .find(|(r, _)| r.role == Role::Reference)
        .and_then(|(_, rec)| rec.as_ref());
    let region = reference.map(|r| compare::region_vertices(&r.result));
    let mut reference_row = None;
    let mut grid = Vec::new();
    let mut grid_runs = Vec::new();
    let mut stab = Vec::new();
    let mut plots = Vec::new();
    let mut total_s = 0.0;
    let mut levels = Vec::new();
    let mut nu_runs = Vec::new();
    for (run, rec) in plan.runs.iter().zip(&records) {
        let Some(rec) = rec else { continue };
        total_s += rec.wall_s;
        if matches!(run.role, Role::Convergence | Role::Refined) {
            plots.push((run.config.label.clone(), rec.result.forces_for_plot()));
            levels.push(&rec.result);
            continue;
        }
        if run.role == Role::Incompressible {
            nu_runs.push(&rec.result);
            continue;
        }
        let errors = match (reference, &region) {
            (Some(refr), Some(region)) if run.role != Role::Stability => {
                Some(compare::compare(&refr.result, region, &rec.result))
            }
            _ => None,
        };
        let row = Row::of(&rec.result, rec.speed_mps, errors);
        match run.role {
            Role::Reference => {
                plots.push((run.config.label.clone(), rec.result.forces_for_plot()));
                reference_row = Some(row);
            }
            Role::Grid => {
                plots.push((run.config.label.clone(), rec.result.forces_for_plot()));
                grid_runs.push(&rec.result);
                grid.push(row);
            }
            Role::Stability => stab.push(row),
            Role::Convergence | Role::Refined | Role::Incompressible => {}
        }
    }
    let planned = Plan::new(plan.quick);
    // The reference is one of the levels when the plan made it one.
    if let (true, Some(r), false) = (planned.reference_is_a_level(), reference, levels.is_empty()) {
        levels.push(&r.result);
    }
    // The mesher's levels in the planned order; the one-shape families.
    let main: Vec<_> = planned
        .convergence
        .iter()
        .filter_map(|c| levels.iter().find(|r| r.config.label == c.label).copied())
        .collect();
    let families: Vec<_> = convergence::families(&levels)
        .iter()
        .map(|f| convergence::evaluate(f))
        .collect();
    let (stability, checks) = stability::evaluate(&planned.stability, stab);
    let pairs: Vec<_> = grid_runs.into_iter().zip(&grid).collect();
    let contact_rules = rules::evaluate(&pairs);
    let result = StudyResult {
        reference: reference_row,
        contact_rules,
        grid,
        stability,
        checks,
        incompressible: (!nu_runs.is_empty())
            .then(|| {
                let at = planned
                    .convergence
                    .get(convergence::SWEEP_LEVEL)
                    .unwrap_or(&planned.reference);
                incompressible::evaluate(&main, at, &nu_runs)
            })
            .flatten(),
        convergence: (main.len() >= 2 || !families.is_empty()).then(|| convergence::Convergence {
            refined: families,
            ..convergence::evaluate(&main)
        }),
        total_s,
        window_s: plan.window_s,
        rate_hz: plan.rate_hz,
        dt_s: plan.dt_s,
        quick: plan.quick,
        absent,
    };
    output::write_all(out, &result, &plots)?;
    Ok(result)
}
