//! The stability sweep: Poisson's ratio, Young's modulus and spatula speed
//! driven to their extremes, one at a time around a nominal run (E = 3 kPa,
//! nu = 0.45, the trajectory's own speed), for each strategy swept.
//!
//! Each run reports whether it stayed finite, the worst element volume ratio
//! `min det F` (from all node displacements, every step), the solver
//! iterations and a force error at the last step (both instruments' net
//! force magnitudes summed), defined per dimension:
//!
//! * Young's modulus: `F(E) E0 / E` against the nominal `F(E0)`
//!   (elasticity with enforced displacements is linear in E: the error
//!   should vanish);
//! * speed: `F(v)` against the nominal `F(v0)` (the model is quasi-static: the
//!   end state should not depend on speed unless contact is lost);
//! * Poisson's ratio: reported as the ratio `F(nu) / F(0.45)` (not an error:
//!   a stiffer response near incompressibility is physical, but linear
//!   tetrahedra overshoot it by locking).
//!
//! A run *fails* when it produced a non-finite value, a solver step failed, an
//! element inverted (`det F <= 0`), or its force error exceeds
//! [`FORCE_ERROR_LIMIT_PCT`].

// Negated comparisons are deliberate: NaN must fail the checks.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::Row;
use super::config::Config;
use super::scenario::ScenarioSpec;
use crate::trajectory::TrajectoryError;
use fissure_server::fem::Strategy;
use serde::Serialize;

/// Force error beyond which a run is listed as failing, %.
pub const FORCE_ERROR_LIMIT_PCT: f64 = 25.0;
/// Largest deviation of `F(E) E0 / E` from `F(E0)` the check accepts, %.
pub const LINEAR_IN_E_TOL_PCT: f64 = 1.0;
/// Smallest `F(0.499) / F(0.45)` of the linear strategy the check accepts:
/// linear tetrahedra lock near incompressibility.
pub const LOCKING_MIN_RATIO: f64 = 1.5;

/// The values swept for one strategy.
#[derive(Debug, Clone)]
pub struct StrategySweep {
    /// The strategy.
    pub strategy: Strategy,
    /// Poisson's ratios (0.45 is the nominal run).
    pub nus: Vec<f64>,
    /// Young's moduli, Pa (3 kPa is the nominal run).
    pub youngs_pa: Vec<f64>,
    /// Mean spatula speeds, m/s.
    pub speeds_mps: Vec<f64>,
}

/// What is swept.
#[derive(Debug, Clone)]
pub struct Sweep {
    /// Phantom preset.
    pub preset: String,
    /// Source nodes a face.
    pub nodes_per_face: u32,
    /// Per strategy: the values (the costly strategies get fewer).
    pub strategies: Vec<StrategySweep>,
    /// Force samples per second of the speed runs (poses per second of
    /// scaled time: a fast spatula jumps far between samples).
    pub speed_rate_hz: f64,
    /// Nominal window, s.
    pub window_s: f64,
    /// Force samples per second of the other runs.
    pub rate_hz: f64,
}

impl Sweep {
    /// The full sweep, on the coarse phantom (the sweep is about the
    /// solvers' and the collision's behaviour at the extremes, which the
    /// coarse mesh shows at a fraction of the cost): linear `compliance`
    /// over every value, `corotational` over the extremes, `neo-hookean`
    /// over the hardest ones (it costs about a second a step).
    pub fn full() -> Self {
        Self {
            preset: "coarse".into(),
            nodes_per_face: 150,
            strategies: vec![
                StrategySweep {
                    strategy: Strategy::Compliance,
                    nus: vec![0.3, 0.49, 0.499],
                    youngs_pa: vec![100.0, 1e3, 1e4, 1e5, 1e6],
                    speeds_mps: vec![0.001, 0.01, 0.1, 1.0],
                },
                StrategySweep {
                    strategy: Strategy::Corotational,
                    nus: vec![0.3, 0.499],
                    youngs_pa: vec![100.0, 1e6],
                    speeds_mps: vec![0.1, 1.0],
                },
                StrategySweep {
                    strategy: Strategy::NeoHookean,
                    nus: vec![0.499],
                    youngs_pa: vec![1e6],
                    speeds_mps: vec![1.0],
                },
            ],
            speed_rate_hz: 1000.0,
            window_s: 1.4,
            rate_hz: 200.0,
        }
    }

    /// The CI sweep: coarse, 30 nodes a face, linear `compliance`, the
    /// extremes only.
    pub fn quick() -> Self {
        Self {
            preset: "coarse".into(),
            nodes_per_face: 30,
            strategies: vec![StrategySweep {
                strategy: Strategy::Compliance,
                nus: vec![0.3, 0.499],
                youngs_pa: vec![100.0, 1e6],
                speeds_mps: vec![0.01, 1.0],
            }],
            speed_rate_hz: 500.0,
            window_s: 1.4,
            rate_hz: 50.0,
        }
    }

    fn nominal(&self, strategy: Strategy) -> Config {
        Config {
            sweep: "stability".into(),
            preset: self.preset.clone(),
            strategy,
            nodes_per_face: self.nodes_per_face,
            ..Config::baseline()
        }
    }

    /// The runs: per strategy, the nominal run first, then nu, E and speed;
    /// deformation interval `dt_s`. A speed run plays the trajectory scaled
    /// so that its mean handle speed is the one swept.
    pub fn configs(&self, dt_s: f64) -> Result<Vec<(Config, ScenarioSpec)>, TrajectoryError> {
        let base = ScenarioSpec {
            window_s: self.window_s,
            time_scale: 1.0,
            rate_hz: self.rate_hz,
            dt_s,
        };
        let v0 = base.scenario()?.mean_speed_mps;
        let mut out = Vec::new();
        for ss in &self.strategies {
            let nominal = self.nominal(ss.strategy);
            let mut push = |config: Config, spec: ScenarioSpec| out.push((config.labelled(), spec));
            push(
                Config {
                    sweep: "nominal".into(),
                    ..nominal.clone()
                },
                base,
            );
            for &nu in ss.nus.iter().filter(|&&n| n != nominal.nu) {
                push(
                    Config {
                        sweep: "nu".into(),
                        nu,
                        ..nominal.clone()
                    },
                    base,
                );
            }
            for &e in ss.youngs_pa.iter().filter(|&&e| e != nominal.youngs_pa) {
                push(
                    Config {
                        sweep: "E".into(),
                        youngs_pa: e,
                        ..nominal.clone()
                    },
                    base,
                );
            }
            for &v in &ss.speeds_mps {
                let time_scale = v0 / v;
                push(
                    Config {
                        sweep: "speed".into(),
                        time_scale,
                        ..nominal.clone()
                    },
                    ScenarioSpec {
                        time_scale,
                        rate_hz: self.speed_rate_hz,
                        ..base
                    },
                );
            }
        }
        Ok(out)
    }
}

/// A stability row: the run and its verdict.
#[derive(Debug, Clone, Serialize)]
pub struct StabilityRow {
    /// The run.
    #[serde(flatten)]
    pub row: Row,
    /// Swept dimension: `nominal`, `nu`, `E`, `speed`.
    pub dimension: String,
    /// Force error against the nominal run (see the module doc), %; `None` for nu.
    pub force_error_pct: Option<f64>,
    /// `F / F(nominal)` (both instruments' final magnitudes summed).
    pub force_ratio: f64,
    /// Whether the run stayed usable.
    pub stable: bool,
    /// Why not.
    pub reason: Option<String>,
}

/// A check over the sweep.
#[derive(Debug, Clone, Serialize)]
pub struct Check {
    /// What is checked.
    pub name: String,
    /// Whether it holds.
    pub passed: bool,
    /// The measured numbers.
    pub detail: String,
}

fn total_force(r: &Row) -> f64 {
    r.final_force_n[0] + r.final_force_n[1]
}

/// Verdicts and checks of the sweep's runs (in [`Sweep::configs`] order).
pub fn evaluate(sweep: &Sweep, runs: Vec<Row>) -> (Vec<StabilityRow>, Vec<Check>) {
    let mut rows: Vec<StabilityRow> = Vec::new();
    let mut checks = Vec::new();
    if runs.is_empty() {
        return (rows, checks);
    }
    for s in sweep.strategies.iter().map(|ss| ss.strategy) {
        let mine: Vec<&Row> = runs.iter().filter(|r| r.config.strategy == s).collect();
        let Some(nominal) = mine.iter().find(|r| r.config.sweep == "nominal") else {
            continue;
        };
        let f0 = total_force(nominal);
        let e0 = nominal.config.youngs_pa;
        for r in &mine {
            let f = total_force(r);
            let ratio = f / f0;
            let err = match r.config.sweep.as_str() {
                "E" => Some(100.0 * (f * e0 / r.config.youngs_pa - f0) / f0),
                "speed" | "nominal" => Some(100.0 * (f - f0) / f0),
                _ => None,
            };
            let mut reasons = Vec::new();
            if !r.finite {
                reasons.push("non-finite displacement or force".to_string());
            }
            if let Some(fail) = &r.failure {
                reasons.push(format!("{} failed step(s), first: {fail}", r.failed_steps));
            }
            if !(r.min_det_f > 0.0) {
                reasons.push(format!("element inverted (min det F = {:.3})", r.min_det_f));
            }
            if let Some(e) = err
                && !(e.abs() <= FORCE_ERROR_LIMIT_PCT)
            {
                reasons.push(format!(
                    "force off by {e:.1}% (limit {FORCE_ERROR_LIMIT_PCT}%)"
                ));
            }
            rows.push(StabilityRow {
                row: (*r).clone(),
                dimension: r.config.sweep.clone(),
                force_error_pct: err,
                force_ratio: ratio,
                stable: reasons.is_empty(),
                reason: (!reasons.is_empty()).then(|| reasons.join("; ")),
            });
        }
        // Linear in E.
        let e_err: Vec<f64> = rows
            .iter()
            .filter(|r| r.row.config.strategy == s && r.dimension == "E")
            .filter_map(|r| r.force_error_pct)
            .collect();
        if !e_err.is_empty() {
            let worst = e_err.iter().fold(0.0f64, |a, e| a.max(e.abs()));
            checks.push(Check {
                name: format!(
                    "{}: force linear in E within {LINEAR_IN_E_TOL_PCT}%",
                    s.name()
                ),
                passed: worst <= LINEAR_IN_E_TOL_PCT,
                detail: format!("worst |F(E) E0/E - F(E0)| / F(E0) = {worst:.2e}%"),
            });
        }
        // Locking of linear tetrahedra.
        if s == Strategy::Compliance
            && let Some(r) = rows.iter().find(|r| {
                r.row.config.strategy == s && r.dimension == "nu" && r.row.config.nu >= 0.499
            })
        {
            checks.push(Check {
                name: format!(
                    "compliance: nu 0.499 locks (F(0.499) / F(0.45) >= {LOCKING_MIN_RATIO})"
                ),
                passed: r.force_ratio >= LOCKING_MIN_RATIO,
                detail: format!("F(0.499) / F(0.45) = {:.3}", r.force_ratio),
            });
        }
    }
    let nonfinite: Vec<&str> = rows
        .iter()
        .filter(|r| !r.row.finite)
        .map(|r| r.row.config.label.as_str())
        .collect();
    checks.push(Check {
        name: "every run finite (no NaN or infinity)".into(),
        passed: nonfinite.is_empty(),
        detail: if nonfinite.is_empty() {
            format!("{} runs", rows.len())
        } else {
            format!("non-finite: {}", nonfinite.join(", "))
        },
    });
    let nominal_ok = rows
        .iter()
        .filter(|r| r.dimension == "nominal")
        .all(|r| r.stable && r.row.min_det_f > 0.0);
    checks.push(Check {
        name: "nominal runs stable, no inverted element".into(),
        passed: nominal_ok,
        detail: rows
            .iter()
            .filter(|r| r.dimension == "nominal")
            .map(|r| format!("{}: min det F {:.3}", r.row.config.label, r.row.min_det_f))
            .collect::<Vec<_>>()
            .join(", "),
    });
    (rows, checks)
}
