//! The haptic error of a configuration: its force samples against a full
//! solve at the same poses, from what a run records anyway.
//!
//! **Where it is measured.** The stepped runner answers a force sample at
//! time `t` from the last step strictly before `t`, and runs step `k` (at
//! `t_k`) with each instrument's pose and collision history of its sample
//! at `t_k` ([`SteppedRunner`](fissure_engine::sim::core::stepped::SteppedRunner)).
//! So where a sample falls on a step's instant, the sample (answered by
//! the force loop from a model a whole interval old) and the step (the
//! full solve at that sample's poses and history) answer the same question,
//! and their difference is the force loop's error at its largest lag. The
//! check costs nothing beyond the run.
//!
//! Per instrument and checked instant, `e = |F_sample - F_step|` (N); the
//! run's figures are `max e` and `sqrt(mean e^2)` over instants and
//! instruments, in % of the run's peak `|F_step|` (as `fissure bench
//! haptic` reports, which checks every sample against a full solve chained
//! at every sample; here the full solve is the run's own step, chained at
//! the step interval, which is the same answer for the linear strategies
//! on the rest shape and can differ for the others where the step's
//! answer depends on where it started, docs/haptic-bench.md). Instants
//! whose step failed (it keeps the last good state, not a solve at those
//! poses) are not checked. A sample matches a step when their times agree
//! to [`SAME_INSTANT_S`].

use nalgebra::Vector3;
use serde::Serialize;

/// Two times within this are one instant, s (the scenario's sample times
/// `j / rate` and the runner's step times `t_0 + k dt` are computed by
/// different products, so they may differ in the last bits).
pub const SAME_INSTANT_S: f64 = 1e-9;

/// A run's force samples against its steps at the same instants.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct HapticError {
    /// Largest `|F_sample - F_step|` over the checked instants and the
    /// instruments, % of the run's peak step force.
    pub max_pct: f64,
    /// Root mean square of the same, % of the peak.
    pub rms_pct: f64,
    /// The largest difference itself, N.
    pub max_n: f64,
    /// Instants checked (samples on a successful step's instant).
    pub checked: usize,
}

/// The steps and samples of a run, as [`at_step_instants`] reads them.
pub struct Series<'a> {
    /// Step times, s.
    pub step_t: &'a [f64],
    /// Each step's net force per instrument, N.
    pub step_force: &'a [Vec<Vector3<f64>>],
    /// Whether each step failed (empty: none did).
    pub step_failed: &'a [bool],
    /// Sample times, s (increasing).
    pub sample_t: &'a [f64],
    /// Each sample's force per instrument, N.
    pub sample_force: &'a [Vec<Vector3<f64>>],
}

/// The haptic error of a run (module documentation); `None` when no
/// sample falls on a successful step's instant or no step pushes.
pub fn at_step_instants(s: &Series<'_>) -> Option<HapticError> {
    let peak = s
        .step_force
        .iter()
        .flatten()
        .map(|f| f.norm())
        .fold(0.0, f64::max);
    if peak <= 0.0 {
        return None;
    }
    let (mut max_n, mut sum_sq, mut terms, mut checked) = (0.0f64, 0.0, 0usize, 0usize);
    let mut j = 0;
    for (k, &t) in s.step_t.iter().enumerate() {
        if s.step_failed.get(k).copied().unwrap_or(false) {
            continue;
        }
        while j < s.sample_t.len() && s.sample_t[j] < t - SAME_INSTANT_S {
            j += 1;
        }
        if j == s.sample_t.len() {
            break;
        }
        if (s.sample_t[j] - t).abs() > SAME_INSTANT_S {
            continue;
        }
        checked += 1;
        for (fs, ff) in s.sample_force[j].iter().zip(&s.step_force[k]) {
            let e = (fs - ff).norm();
            max_n = max_n.max(e);
            sum_sq += e * e;
            terms += 1;
        }
    }
    (terms > 0).then(|| HapticError {
        max_pct: 100.0 * max_n / peak,
        rms_pct: 100.0 * (sum_sq / terms as f64).sqrt() / peak,
        max_n,
        checked,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn z(f: f64) -> Vector3<f64> {
        Vector3::new(0.0, 0.0, f)
    }

    /// [`at_step_instants`] of these series.
    fn error(
        step_t: &[f64],
        step_force: &[Vec<Vector3<f64>>],
        step_failed: &[bool],
        sample_t: &[f64],
        sample_force: &[Vec<Vector3<f64>>],
    ) -> Option<HapticError> {
        at_step_instants(&Series {
            step_t,
            step_force,
            step_failed,
            sample_t,
            sample_force,
        })
    }

    /// Steps every 50 ms from 5 ms, samples every 5 ms from 5 ms (the
    /// study's scenario), as products the way the scenario and the runner
    /// form them.
    fn times(steps: usize) -> (Vec<f64>, Vec<f64>) {
        let step_t = (1..=steps).map(|k| 0.005 + k as f64 * 0.05).collect();
        let sample_t = (1..=10 * steps + 1).map(|j| j as f64 / 200.0).collect();
        (step_t, sample_t)
    }

    #[test]
    fn samples_equal_to_their_steps_have_no_error_whatever_between() {
        let (step_t, sample_t) = times(4);
        let step_force: Vec<_> = (0..4).map(|k| vec![z(0.1 * (k + 1) as f64)]).collect();
        // Between step instants the samples lag (any value): not checked.
        let sample_force: Vec<_> = sample_t
            .iter()
            .map(|&t| {
                let k = step_t.iter().position(|&s| (s - t).abs() < 1e-9);
                vec![z(k.map_or(7.0, |k| 0.1 * (k + 1) as f64))]
            })
            .collect();
        let e = error(&step_t, &step_force, &[], &sample_t, &sample_force).unwrap();
        assert_eq!(e.checked, 4);
        assert_eq!((e.max_pct, e.rms_pct, e.max_n), (0.0, 0.0, 0.0));
    }

    #[test]
    fn the_error_is_the_sample_step_difference_in_percent_of_the_peak_step_force() {
        let (step_t, sample_t) = times(4);
        // Peak 0.4 N; two instruments.
        let step_force: Vec<_> = (0..4)
            .map(|k| vec![z(0.1 * (k + 1) as f64), Vector3::new(0.05, 0.0, 0.0)])
            .collect();
        let mut sample_force: Vec<_> = sample_t
            .iter()
            .map(|&t| {
                let k = step_t
                    .iter()
                    .position(|&s| (s - t).abs() < 1e-9)
                    .unwrap_or(0);
                step_force[k].clone()
            })
            .collect();
        // At step 2's instant the first instrument's sample is 0.02 N low,
        // the other's 0.01 N off sideways.
        let j = sample_t
            .iter()
            .position(|&t| (t - step_t[2]).abs() < 1e-9)
            .unwrap();
        sample_force[j][0].z -= 0.02;
        sample_force[j][1].y += 0.01;
        let e = error(&step_t, &step_force, &[], &sample_t, &sample_force).unwrap();
        assert_eq!(e.checked, 4);
        assert!((e.max_n - 0.02).abs() < 1e-15);
        assert!((e.max_pct - 5.0).abs() < 1e-12, "{}", e.max_pct);
        // sqrt((0.02^2 + 0.01^2) / 8) / 0.4.
        let rms = 100.0 * ((0.02f64.powi(2) + 0.01f64.powi(2)) / 8.0).sqrt() / 0.4;
        assert!((e.rms_pct - rms).abs() < 1e-12, "{} {rms}", e.rms_pct);
    }

    #[test]
    fn a_failed_step_is_not_a_full_solve_and_is_not_checked() {
        let (step_t, sample_t) = times(3);
        let step_force: Vec<_> = (0..3).map(|_| vec![z(0.2)]).collect();
        let sample_force: Vec<_> = sample_t
            .iter()
            .map(|&t| {
                // Off only at the failed step's instant.
                let off = (t - step_t[1]).abs() < 1e-9;
                vec![z(if off { 0.1 } else { 0.2 })]
            })
            .collect();
        let series =
            |failed: &[bool]| error(&step_t, &step_force, failed, &sample_t, &sample_force);
        let e = series(&[false, true, false]).unwrap();
        assert_eq!((e.checked, e.max_n), (2, 0.0));
        // Counted as a solve it would give the 0.1 N difference.
        let e = series(&[]).unwrap();
        assert_eq!(e.checked, 3);
        assert!((e.max_n - 0.1).abs() < 1e-15);
    }

    #[test]
    fn no_push_or_no_common_instant_gives_no_figure() {
        let (step_t, sample_t) = times(2);
        let zero: Vec<_> = (0..2).map(|_| vec![z(0.0)]).collect();
        let samples: Vec<_> = sample_t.iter().map(|_| vec![z(0.0)]).collect();
        assert!(error(&step_t, &zero, &[], &sample_t, &samples).is_none());
        let pushed: Vec<_> = (0..2).map(|_| vec![z(0.1)]).collect();
        let shifted: Vec<f64> = sample_t.iter().map(|t| t + 0.0025).collect();
        assert!(error(&step_t, &pushed, &[], &shifted, &samples).is_none());
    }
}
