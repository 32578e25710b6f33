//! The scripted scenario of the study: the bundled Sylvian opening (both
//! spatulas), resampled at a fixed force-loop rate and optionally played
//! faster or slower.
//!
//! The bundled trajectories run 2 s at 1 kHz: 0-0.6 s the spatulas slide
//! 20 mm into the left Sylvian fissure, 0.6-1.4 s they spread its walls
//! apart (3 mm each), then they hold. The study plays the window
//! `[0, window_s]` of nominal time (default 1.4 s: insertion and opening),
//! scaled by `time_scale` (`> 1` is slower). Poses are sampled at
//! `rate_hz` of *scaled* time by linear interpolation of the positions and
//! normalised linear interpolation of the orientations (the bundled
//! orientations are constant).

use crate::client::trajectory::{Trajectory, Waypoint};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// What a run plays, as a plan file holds it: the window, the time scale,
/// the force-loop rate and the deformation interval of
/// [`Scenario::sylvian`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ScenarioSpec {
    /// Nominal window of the trajectory played, s.
    pub window_s: f64,
    /// Time scale (`> 1` slower).
    pub time_scale: f64,
    /// Force samples per second of scaled time.
    pub rate_hz: f64,
    /// Deformation interval, s.
    pub dt_s: f64,
}

/// End of a run, s of scaled time: the motion, then a hold of three
/// deformation steps at the last pose (a fast run must still show its end
/// state).
fn end_of(window_s: f64, time_scale: f64, dt_s: f64) -> f64 {
    window_s * time_scale + 3.0 * dt_s
}

/// The files a study's runs read: the scene and the two trajectories
/// (bundled names, or files such as a study folder's `inputs/`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Inputs {
    /// The scene the configurations edit.
    pub scene: String,
    /// The left spatula's trajectory.
    pub left: String,
    /// The right spatula's trajectory.
    pub right: String,
}

impl Inputs {
    /// The bundled scene and trajectories.
    pub fn bundled() -> Self {
        Self {
            scene: "sylvian".into(),
            left: "sylvian-open-left".into(),
            right: "sylvian-open-right".into(),
        }
    }
}

impl ScenarioSpec {
    /// The scenario over `inputs`.
    pub fn scenario_in(
        &self,
        inputs: &Inputs,
    ) -> Result<Scenario, crate::client::trajectory::TrajectoryError> {
        let left = Trajectory::load(&inputs.left)?;
        let right = Trajectory::load(&inputs.right)?;
        let mut s = Scenario::new(
            &[("left".into(), left), ("right".into(), right)],
            self.window_s,
            self.time_scale,
            self.rate_hz,
            self.dt_s,
        );
        s.scene.clone_from(&inputs.scene);
        Ok(s)
    }

    /// Deformation steps of a run of this scenario.
    pub fn steps(&self) -> usize {
        crate::lab::study::driver::steps_until(
            end_of(self.window_s, self.time_scale, self.dt_s),
            self.dt_s,
        )
    }

    /// The scenario: the bundled Sylvian opening resampled.
    pub fn scenario(&self) -> Result<Scenario, crate::client::trajectory::TrajectoryError> {
        Scenario::sylvian(self.window_s, self.time_scale, self.rate_hz, self.dt_s)
    }
}

/// One instrument's resampled poses.
#[derive(Debug, Clone)]
pub struct Track {
    /// Instrument name in the scene.
    pub instrument: String,
    /// Poses, one per sample time of the scenario.
    pub poses: Vec<Isometry3<f64>>,
}

/// The scenario a run plays.
#[derive(Debug, Clone)]
pub struct Scenario {
    /// Sample times, s (scaled time), increasing, first `> 0`.
    pub times: Vec<f64>,
    /// One track per instrument, in scene order.
    pub tracks: Vec<Track>,
    /// Deformation interval, s (the scene's, 0.02 s).
    pub dt_s: f64,
    /// Time scale applied to the nominal trajectory (`> 1`: slower).
    pub time_scale: f64,
    /// Mean handle speed of the first instrument over the window, m/s.
    pub mean_speed_mps: f64,
    /// End of the run, s (scaled time).
    pub end_s: f64,
    /// The scene the configurations edit: a bundled name or a file.
    pub scene: String,
}

/// Position and orientation of a trajectory at nominal time `t` (s), clamped
/// to its ends.
pub fn pose_at(points: &[Waypoint], t: f64) -> Isometry3<f64> {
    let q = |w: &Waypoint| Quaternion::new(w.qw, w.qx, w.qy, w.qz);
    let p = |w: &Waypoint| Vector3::new(w.x_m, w.y_m, w.z_m);
    let iso = |pos: Vector3<f64>, quat: Quaternion<f64>| {
        Isometry3::from_parts(Translation3::from(pos), UnitQuaternion::new_normalize(quat))
    };
    let first = &points[0];
    let last = &points[points.len() - 1];
    if t <= first.t_s {
        return iso(p(first), q(first));
    }
    if t >= last.t_s {
        return iso(p(last), q(last));
    }
    // First waypoint with time > t (exists since t < last.t_s).
    let hi = points.partition_point(|w| w.t_s <= t);
    let (a, b) = (&points[hi - 1], &points[hi]);
    let span = b.t_s - a.t_s;
    let s = if span > 0.0 { (t - a.t_s) / span } else { 1.0 };
    let mut qb = q(b);
    if q(a).dot(&qb) < 0.0 {
        qb = -qb;
    }
    iso(p(a) + (p(b) - p(a)) * s, q(a) * (1.0 - s) + qb * s)
}

/// Path length of the handle over nominal time `[0, window]`, m.
pub fn path_length(points: &[Waypoint], window_s: f64) -> f64 {
    let mut len = 0.0;
    let mut prev: Option<Vector3<f64>> = None;
    for w in points.iter().filter(|w| w.t_s <= window_s) {
        let p = Vector3::new(w.x_m, w.y_m, w.z_m);
        if let Some(q) = prev {
            len += (p - q).norm();
        }
        prev = Some(p);
    }
    len
}

impl Scenario {
    /// Resamples `trajectories` (instrument name, trajectory) over the nominal
    /// window `[0, window_s]`, played `time_scale` times slower, at `rate_hz`
    /// poses per second of scaled time; deformation interval `dt_s`.
    pub fn new(
        trajectories: &[(String, Trajectory)],
        window_s: f64,
        time_scale: f64,
        rate_hz: f64,
        dt_s: f64,
    ) -> Self {
        let end_s = end_of(window_s, time_scale, dt_s);
        let n = (end_s * rate_hz).floor().max(1.0) as usize;
        let times: Vec<f64> = (1..=n).map(|j| j as f64 / rate_hz).collect();
        let tracks = trajectories
            .iter()
            .map(|(name, tr)| Track {
                instrument: name.clone(),
                poses: times
                    .iter()
                    .map(|&t| pose_at(&tr.points, t / time_scale))
                    .collect(),
            })
            .collect();
        let mean_speed_mps = trajectories.first().map_or(0.0, |(_, tr)| {
            path_length(&tr.points, window_s) / (window_s * time_scale)
        });
        Self {
            times,
            tracks,
            dt_s,
            time_scale,
            mean_speed_mps,
            end_s,
            scene: "sylvian".into(),
        }
    }

    /// The bundled Sylvian opening (`sylvian-open-left` and `-right`).
    pub fn sylvian(
        window_s: f64,
        time_scale: f64,
        rate_hz: f64,
        dt_s: f64,
    ) -> Result<Self, crate::client::trajectory::TrajectoryError> {
        let left = Trajectory::load("sylvian-open-left")?;
        let right = Trajectory::load("sylvian-open-right")?;
        Ok(Self::new(
            &[("left".into(), left), ("right".into(), right)],
            window_s,
            time_scale,
            rate_hz,
            dt_s,
        ))
    }

    /// Deformation steps the run takes (`k dt <= end`).
    pub fn steps(&self) -> usize {
        crate::lab::study::driver::steps_until(self.end_s, self.dt_s)
    }
}
