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
//!   tetrahedra overshoot it by locking). The locking-free
//!   `tet4-nodal-pressure` element is swept too, and its ratio at the
//!   largest `nu` is checked against the same ratio of a reference of that
//!   element on the finest mesh (`paper-48k`), the converged nearly
//!   incompressible answer of the sweep, within
//!   [`NEARLY_INCOMPRESSIBLE_TOL_PCT`].
//!
//! A run *fails* when it produced a non-finite value, a solver step failed, an
//! element inverted (`det F <= 0`), or its force error exceeds
//! [`FORCE_ERROR_LIMIT_PCT`].

// Negated comparisons are deliberate: NaN must fail the checks.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use super::Row;
use super::config::Config;
use super::scenario::ScenarioSpec;
use crate::client::trajectory::TrajectoryError;
use fissure_engine::fem::{Element, Strategy};
use serde::Serialize;

/// Force error beyond which a run is listed as failing, %.
pub const FORCE_ERROR_LIMIT_PCT: f64 = 25.0;
/// Largest deviation of `F(E) E0 / E` from `F(E0)` the check accepts, %.
pub const LINEAR_IN_E_TOL_PCT: f64 = 1.0;
/// Smallest `F(0.499) / F(0.45)` of the linear strategy the check accepts:
/// linear tetrahedra lock near incompressibility.
pub const LOCKING_MIN_RATIO: f64 = 1.5;
/// Largest deviation of the nodal-pressure element's `F(nu) / F(0.45)` at
/// the sweep's largest `nu` from the same ratio of its reference on the
/// finest mesh, %.
pub const NEARLY_INCOMPRESSIBLE_TOL_PCT: f64 = 10.0;
/// The finest mesh of the sweep, where the nodal-pressure reference runs.
pub const REFERENCE_PRESET: &str = "paper-48k";

/// The values swept for one strategy.
#[derive(Debug, Clone)]
pub struct StrategySweep {
    /// The strategy.
    pub strategy: Strategy,
    /// The element formulation.
    pub element: Element,
    /// The phantom preset of these runs when not the sweep's (the
    /// nodal-pressure reference runs on [`REFERENCE_PRESET`]).
    pub preset: Option<String>,
    /// Mesh the preset with the proven mesher (the finest mesh's extremes:
    /// paper-48k proven is the study's 204k level).
    pub proven: bool,
    /// Poisson's ratios (0.45 is the nominal run).
    pub nus: Vec<f64>,
    /// Young's moduli, Pa (3 kPa is the nominal run).
    pub youngs_pa: Vec<f64>,
    /// Mean spatula speeds, m/s.
    pub speeds_mps: Vec<f64>,
}

impl StrategySweep {
    /// `compliance` with `element` on the sweep's preset, no values yet.
    pub fn linear(element: Element) -> Self {
        Self {
            strategy: Strategy::Compliance,
            element,
            preset: None,
            proven: false,
            nus: Vec::new(),
            youngs_pa: Vec::new(),
            speeds_mps: Vec::new(),
        }
    }

    /// The converged nearly incompressible reference: the nodal-pressure
    /// element on [`REFERENCE_PRESET`], at 0.45 and 0.4999.
    pub fn nearly_incompressible_reference() -> Self {
        Self {
            preset: Some(REFERENCE_PRESET.into()),
            nus: vec![0.4999],
            ..Self::linear(Element::Tet4NodalPressure)
        }
    }

    /// Young's modulus and speed at their extremes on the finest mesh the
    /// study sweeps (the 204k level, paper-48k meshed by the proven
    /// mesher) with the nodal-pressure element: a softer brain deforms its
    /// smallest elements most, a fast spatula crosses several of them
    /// between two samples.
    pub fn finest_mesh_extremes() -> Self {
        Self {
            preset: Some(REFERENCE_PRESET.into()),
            proven: true,
            youngs_pa: vec![100.0, 1e6],
            speeds_mps: vec![1.0],
            ..Self::linear(Element::Tet4NodalPressure)
        }
    }

    /// Whether `r` is one of its runs.
    fn owns(&self, sweep_preset: &str, c: &Config) -> bool {
        c.strategy == self.strategy
            && c.element == self.element
            && c.preset == self.preset.as_deref().unwrap_or(sweep_preset)
            && c.proven == self.proven
    }

    /// Its name in the checks.
    fn name(&self) -> String {
        let mut n = self.strategy.name().to_string();
        if self.element != Element::Tet4 {
            n.push_str(&format!(" {}", self.element.name()));
        }
        if let Some(p) = &self.preset {
            n.push_str(&format!(" on {p}"));
        }
        if self.proven {
            n.push_str(" proven (204k)");
        }
        n
    }
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
    /// over the hardest ones (it costs about a second a step); and the
    /// extremes of E and speed on the finest mesh
    /// ([`StrategySweep::finest_mesh_extremes`]).
    pub fn full() -> Self {
        Self {
            preset: "coarse".into(),
            nodes_per_face: 150,
            strategies: vec![
                StrategySweep {
                    nus: vec![0.3, 0.49, 0.499, 0.4999],
                    youngs_pa: vec![100.0, 1e3, 1e4, 1e5, 1e6],
                    speeds_mps: vec![0.001, 0.01, 0.1, 1.0],
                    ..StrategySweep::linear(Element::Tet4)
                },
                StrategySweep {
                    nus: vec![0.3, 0.49, 0.499, 0.4999],
                    youngs_pa: vec![100.0, 1e6],
                    speeds_mps: vec![0.01, 1.0],
                    ..StrategySweep::linear(Element::Tet4NodalPressure)
                },
                StrategySweep::nearly_incompressible_reference(),
                StrategySweep::finest_mesh_extremes(),
                StrategySweep {
                    strategy: Strategy::Corotational,
                    nus: vec![0.3, 0.499],
                    youngs_pa: vec![100.0, 1e6],
                    speeds_mps: vec![0.1, 1.0],
                    ..StrategySweep::linear(Element::Tet4)
                },
                StrategySweep {
                    strategy: Strategy::NeoHookean,
                    nus: vec![0.499],
                    youngs_pa: vec![1e6],
                    speeds_mps: vec![1.0],
                    ..StrategySweep::linear(Element::Tet4)
                },
            ],
            speed_rate_hz: 1000.0,
            window_s: 1.4,
            rate_hz: 200.0,
        }
    }

    /// The CI sweep: coarse, 30 nodes a face, linear `compliance` with both
    /// elements, the extremes only, and the nodal-pressure reference.
    pub fn quick() -> Self {
        Self {
            preset: "coarse".into(),
            nodes_per_face: 30,
            strategies: vec![
                StrategySweep {
                    nus: vec![0.3, 0.499, 0.4999],
                    youngs_pa: vec![100.0, 1e6],
                    speeds_mps: vec![0.01, 1.0],
                    ..StrategySweep::linear(Element::Tet4)
                },
                StrategySweep {
                    nus: vec![0.499, 0.4999],
                    youngs_pa: vec![],
                    speeds_mps: vec![],
                    ..StrategySweep::linear(Element::Tet4NodalPressure)
                },
                StrategySweep::nearly_incompressible_reference(),
            ],
            speed_rate_hz: 500.0,
            window_s: 1.4,
            rate_hz: 50.0,
        }
    }

    fn nominal(&self, ss: &StrategySweep) -> Config {
        Config {
            sweep: "stability".into(),
            preset: ss.preset.clone().unwrap_or_else(|| self.preset.clone()),
            proven: ss.proven,
            strategy: ss.strategy,
            element: ss.element,
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
            let nominal = self.nominal(ss);
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
    // F(nu) / F(0.45) of the nodal-pressure reference, per nu.
    let reference = sweep
        .strategies
        .iter()
        .find(|ss| ss.element == Element::Tet4NodalPressure && ss.preset.is_some() && !ss.proven);
    let reference_ratio = |nu: f64| -> Option<f64> {
        let ss = reference?;
        let mine: Vec<&Row> = runs
            .iter()
            .filter(|r| ss.owns(&sweep.preset, &r.config))
            .collect();
        let f0 = mine.iter().find(|r| r.config.sweep == "nominal")?;
        let f = mine
            .iter()
            .find(|r| r.config.sweep == "nu" && r.config.nu == nu)?;
        Some(total_force(f) / total_force(f0))
    };
    for ss in &sweep.strategies {
        let s = ss.strategy;
        let owned = |r: &Row| ss.owns(&sweep.preset, &r.config);
        let mine: Vec<&Row> = runs.iter().filter(|r| owned(r)).collect();
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
            .filter(|r| owned(&r.row) && r.dimension == "E")
            .filter_map(|r| r.force_error_pct)
            .collect();
        if !e_err.is_empty() {
            let worst = e_err.iter().fold(0.0f64, |a, e| a.max(e.abs()));
            checks.push(Check {
                name: format!(
                    "{}: force linear in E within {LINEAR_IN_E_TOL_PCT}%",
                    ss.name()
                ),
                passed: worst <= LINEAR_IN_E_TOL_PCT,
                detail: format!("worst |F(E) E0/E - F(E0)| / F(E0) = {worst:.2e}%"),
            });
        }
        // Locking of linear tetrahedra.
        if s == Strategy::Compliance
            && ss.element == Element::Tet4
            && ss.preset.is_none()
            && let Some(r) = rows
                .iter()
                .find(|r| owned(&r.row) && r.dimension == "nu" && r.row.config.nu == 0.499)
        {
            checks.push(Check {
                name: format!(
                    "compliance: nu 0.499 locks (F(0.499) / F(0.45) >= {LOCKING_MIN_RATIO})"
                ),
                passed: r.force_ratio >= LOCKING_MIN_RATIO,
                detail: format!("F(0.499) / F(0.45) = {:.3}", r.force_ratio),
            });
        }
        // No locking with nodal pressure: the ratio at the largest nu
        // follows the converged reference.
        if ss.element == Element::Tet4NodalPressure
            && ss.preset.is_none()
            && let Some(r) = rows
                .iter()
                .filter(|r| owned(&r.row) && r.dimension == "nu")
                .max_by(|a, b| a.row.config.nu.total_cmp(&b.row.config.nu))
        {
            let nu = r.row.config.nu;
            let (passed, detail) = match reference_ratio(nu) {
                Some(want) => {
                    let dev = 100.0 * (r.force_ratio - want) / want;
                    (
                        dev.abs() <= NEARLY_INCOMPRESSIBLE_TOL_PCT,
                        format!(
                            "F({nu}) / F(0.45) = {:.3}, reference {want:.3} ({dev:+.1}%)",
                            r.force_ratio
                        ),
                    )
                }
                None => (false, "the reference's runs are missing".to_string()),
            };
            checks.push(Check {
                name: format!(
                    "{}: F({nu}) / F(0.45) within {NEARLY_INCOMPRESSIBLE_TOL_PCT}% of the {REFERENCE_PRESET} reference",
                    ss.name()
                ),
                passed,
                detail,
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The finest mesh's extremes run on the study's 204k level with the
    /// nodal-pressure element, held at the stem (so the force is linear in
    /// E), and no other strategy's sweep claims their runs, nor theirs the
    /// nearly incompressible reference's on the graded paper-48k.
    #[test]
    fn the_finest_mesh_extremes_run_on_the_204k_level_and_own_only_their_runs() {
        let sweep = Sweep::full();
        let runs = sweep.configs(0.05).expect("the sweep's runs");
        let finest = StrategySweep::finest_mesh_extremes();
        let mine: Vec<&Config> = runs.iter().map(|(c, _)| c).filter(|c| c.proven).collect();
        // Nominal, two moduli, one speed.
        assert_eq!(
            mine.len(),
            4,
            "{:?}",
            mine.iter().map(|c| &c.label).collect::<Vec<_>>()
        );
        for c in &mine {
            assert!(c.label.starts_with("204k/"), "{}", c.label);
            assert_eq!(c.element, Element::Tet4NodalPressure);
            assert_eq!(c.support, super::super::config::Support::Stem);
            c.scene().expect("a valid scene");
        }
        for (c, _) in &runs {
            let claims: Vec<String> = sweep
                .strategies
                .iter()
                .filter(|ss| ss.owns(&sweep.preset, c))
                .map(StrategySweep::name)
                .collect();
            assert_eq!(claims.len(), 1, "{}: {claims:?}", c.label);
            assert_eq!(finest.owns(&sweep.preset, c), c.proven, "{}", c.label);
        }
    }
}
