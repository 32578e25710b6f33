//! A run's result file, and the failure record of a run that could not be
//! computed.
//!
//! `DIR/runs/<id>.cbor` holds everything the merge needs from the run: the
//! configuration and scenario it ran (checked against the plan), what it
//! measured ([`RunResult`]: every step's forces and, for the grid, surface
//! displacements, the timings, the solver's verdicts) and its wall time. It
//! is CBOR (RFC 8949, through `ciborium`): binary, so a paper-size run's
//! surface history stays a few megabytes, and every `f64` comes back with
//! the same bits, NaN and infinities included (JSON has neither). A result
//! file is written to a temporary name and renamed, so a run killed midway
//! leaves no result (the merge reports it missing) and never a truncated one.
//!
//! `DIR/runs/<id>.failed.json` names why a run failed (its setup, or a
//! panic); it is removed when the run is computed again.

use super::StudyError;
use super::config::Config;
use super::driver::RunResult;
use super::plan::PlannedRun;
use super::scenario::ScenarioSpec;
use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The folder of the result files, inside a study folder.
pub const RUNS_DIR: &str = "runs";
/// The result file's format tag.
pub const RECORD_FORMAT: &str = "fissure-study-run/1";

/// Writes `bytes` to `path` through a temporary file in the same folder and
/// a rename (making the folder when it is absent): readers see the old file
/// or the whole new one.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), StudyError> {
    let err = |e: std::io::Error| StudyError::Output {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).map_err(err)?;
    }
    let tmp = path.with_file_name(format!(".{name}.tmp-{}", std::process::id()));
    std::fs::write(&tmp, bytes).map_err(err)?;
    std::fs::rename(&tmp, path).map_err(err)
}

type P3 = [f64; 3];

fn p3(v: &Vector3<f64>) -> P3 {
    [v.x, v.y, v.z]
}

fn v3(a: &P3) -> Vector3<f64> {
    Vector3::new(a[0], a[1], a[2])
}

/// [`RunResult`] with plain arrays for the nalgebra points and vectors.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct StoredResult {
    config: Config,
    tets: usize,
    nodes: usize,
    rest_surface: Vec<P3>,
    triangles: Vec<[u32; 3]>,
    step_t: Vec<f64>,
    step_force: Vec<Vec<P3>>,
    surface_u: Vec<Vec<P3>>,
    step_ms: Vec<f64>,
    collision_ms: Vec<f64>,
    #[serde(default)]
    step_failed: Vec<bool>,
    iterations: Vec<u32>,
    sample_t: Vec<f64>,
    sample_force: Vec<Vec<P3>>,
    sample_us: Vec<f64>,
    min_det_f: f64,
    finite: bool,
    failed_steps: usize,
    failure: Option<String>,
    dropped_outside_roi: usize,
    setup_ms: f64,
    backend_used: String,
    has_local_model: bool,
}

fn vecs(v: &[Vec<Vector3<f64>>]) -> Vec<Vec<P3>> {
    v.iter().map(|s| s.iter().map(p3).collect()).collect()
}

fn unvecs(v: &[Vec<P3>]) -> Vec<Vec<Vector3<f64>>> {
    v.iter().map(|s| s.iter().map(v3).collect()).collect()
}

impl From<&RunResult> for StoredResult {
    fn from(r: &RunResult) -> Self {
        Self {
            config: r.config.clone(),
            tets: r.tets,
            nodes: r.nodes,
            rest_surface: r.rest_surface.iter().map(|p| p3(&p.coords)).collect(),
            triangles: r.triangles.clone(),
            step_t: r.step_t.clone(),
            step_force: vecs(&r.step_force),
            surface_u: vecs(&r.surface_u),
            step_ms: r.step_ms.clone(),
            collision_ms: r.collision_ms.clone(),
            step_failed: r.step_failed.clone(),
            iterations: r.iterations.clone(),
            sample_t: r.sample_t.clone(),
            sample_force: vecs(&r.sample_force),
            sample_us: r.sample_us.clone(),
            min_det_f: r.min_det_f,
            finite: r.finite,
            failed_steps: r.failed_steps,
            failure: r.failure.clone(),
            dropped_outside_roi: r.dropped_outside_roi,
            setup_ms: r.setup_ms,
            backend_used: r.backend_used.clone(),
            has_local_model: r.has_local_model,
        }
    }
}

impl From<StoredResult> for RunResult {
    fn from(s: StoredResult) -> Self {
        Self {
            config: s.config,
            tets: s.tets,
            nodes: s.nodes,
            rest_surface: s.rest_surface.iter().map(|a| Point3::from(v3(a))).collect(),
            triangles: s.triangles,
            step_t: s.step_t,
            step_force: unvecs(&s.step_force),
            surface_u: unvecs(&s.surface_u),
            step_ms: s.step_ms,
            collision_ms: s.collision_ms,
            step_failed: s.step_failed,
            iterations: s.iterations,
            sample_t: s.sample_t,
            sample_force: unvecs(&s.sample_force),
            sample_us: s.sample_us,
            min_det_f: s.min_det_f,
            finite: s.finite,
            failed_steps: s.failed_steps,
            failure: s.failure,
            dropped_outside_roi: s.dropped_outside_roi,
            setup_ms: s.setup_ms,
            backend_used: s.backend_used,
            has_local_model: s.has_local_model,
        }
    }
}

#[derive(Serialize, Deserialize)]
struct StoredRecord {
    format: String,
    id: String,
    scenario: ScenarioSpec,
    speed_mps: f64,
    wall_s: f64,
    result: StoredResult,
}

/// A computed run.
#[derive(Debug, Clone)]
pub struct RunRecord {
    /// The run's id.
    pub id: String,
    /// The scenario it played.
    pub scenario: ScenarioSpec,
    /// Mean handle speed of the scenario, m/s.
    pub speed_mps: f64,
    /// Wall time of the run (setup included), s.
    pub wall_s: f64,
    /// What it measured.
    pub result: RunResult,
}

/// Why a run failed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FailureRecord {
    /// The run's id.
    pub id: String,
    /// The cause.
    pub cause: String,
}

/// The result file of run `id` in study folder `dir`.
pub fn result_path(dir: &Path, id: &str) -> PathBuf {
    dir.join(RUNS_DIR).join(format!("{id}.cbor"))
}

/// The failure record of run `id` in study folder `dir`.
pub fn failure_path(dir: &Path, id: &str) -> PathBuf {
    dir.join(RUNS_DIR).join(format!("{id}.failed.json"))
}

fn bad(path: &Path, message: impl std::fmt::Display) -> StudyError {
    StudyError::Record {
        path: path.to_path_buf(),
        message: message.to_string(),
    }
}

impl RunRecord {
    /// Writes the result file into `dir` (and removes a failure record).
    pub fn write(&self, dir: &Path) -> Result<(), StudyError> {
        let path = result_path(dir, &self.id);
        let stored = StoredRecord {
            format: RECORD_FORMAT.into(),
            id: self.id.clone(),
            scenario: self.scenario,
            speed_mps: self.speed_mps,
            wall_s: self.wall_s,
            result: StoredResult::from(&self.result),
        };
        let mut bytes = Vec::new();
        ciborium::into_writer(&stored, &mut bytes).map_err(|e| bad(&path, e))?;
        write_atomically(&path, &bytes)?;
        let failed = failure_path(dir, &self.id);
        match std::fs::remove_file(&failed) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(bad(&failed, e)),
            _ => Ok(()),
        }
    }

    /// Reads the result file of `run` from `dir`: `None` when there is none;
    /// an error when it is unreadable or holds another run than the plan's.
    pub fn read(dir: &Path, run: &PlannedRun) -> Result<Option<Self>, StudyError> {
        let path = result_path(dir, &run.id);
        let file = match std::fs::File::open(&path) {
            Ok(f) => f,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(bad(&path, e)),
        };
        let stored: StoredRecord = ciborium::from_reader(std::io::BufReader::new(file))
            .map_err(|e| bad(&path, format!("not a result file: {e}")))?;
        if stored.format != RECORD_FORMAT {
            return Err(bad(
                &path,
                format!(
                    "format {:?}, this fissure reads {RECORD_FORMAT:?}",
                    stored.format
                ),
            ));
        }
        if stored.id != run.id
            || stored.result.config != run.config
            || stored.scenario != run.scenario
        {
            return Err(bad(
                &path,
                format!(
                    "holds run {:?} ({}), not the plan's {:?} ({}): compute it again with --force",
                    stored.id, stored.result.config.label, run.id, run.config.label
                ),
            ));
        }
        Ok(Some(Self {
            id: stored.id,
            scenario: stored.scenario,
            speed_mps: stored.speed_mps,
            wall_s: stored.wall_s,
            result: stored.result.into(),
        }))
    }
}

impl FailureRecord {
    /// Writes the failure record into `dir`.
    pub fn write(&self, dir: &Path) -> Result<(), StudyError> {
        let path = failure_path(dir, &self.id);
        let json = serde_json::to_string_pretty(self).map_err(|e| bad(&path, e))?;
        write_atomically(&path, json.as_bytes())
    }

    /// The failure record of run `id` in `dir`, if there is one.
    pub fn read(dir: &Path, id: &str) -> Result<Option<Self>, StudyError> {
        let path = failure_path(dir, id);
        match std::fs::read_to_string(&path) {
            Ok(text) => serde_json::from_str(&text)
                .map(Some)
                .map_err(|e| bad(&path, e)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(bad(&path, e)),
        }
    }
}
