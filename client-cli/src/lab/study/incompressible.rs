//! Poisson's ratio towards incompressibility on the 204k level, with
//! both elements: the reference physics ([`convergence::reference_physics`]:
//! frictionless contact, the scene's foundation, linear elasticity) on the
//! 204k level ([`convergence::SWEEP_LEVEL`]) at `nu` in [`NUS`], with
//! `tet4` and with `tet4-nodal-pressure`.
//!
//! The measure is the stiffening ratio `R(nu) = F(nu) / F(0.45)`, with `F`
//! the sum of both spatulas' net force magnitudes at the last step. Linear
//! tetrahedra lock as `nu -> 1/2` (their `R` grows without bound with the
//! bulk modulus); the nodal-pressure element does not.
//!
//! **The converged nearly incompressible answer** is `R(0.4999)` of the
//! nodal-pressure element in the mesh limit: its values on every
//! convergence level, the last three extrapolated by
//! [`convergence::richardson`] over the levels' element sizes; when they
//! are not in the asymptotic range, the finest level's value stands for it
//! (and the report says so). The target: the sweep level's nodal-pressure
//! `R(0.4999)` within [`TOLERANCE_PCT`] of it.

use super::config::Config;
use super::convergence::{self, Richardson};
use super::driver::RunResult;
use fissure_engine::fem::Element;
use serde::Serialize;

/// Poisson's ratios swept (0.45 is the nominal value).
pub const NUS: [f64; 4] = [0.45, 0.49, 0.499, 0.4999];
/// The nearly incompressible value.
pub const NU_LIMIT: f64 = 0.4999;
/// Largest deviation of the sweep level's nodal-pressure `R(0.4999)` from
/// the converged answer, %.
pub const TOLERANCE_PCT: f64 = 10.0;

/// The runs of the sweep that the convergence levels (`levels`, coarsest
/// first, nodal-pressure at 0.45) do not already hold: both elements at
/// every `nu` on the sweep level `levels[at]`, and the nodal-pressure
/// element at [`NU_LIMIT`] on the others.
pub fn configs(levels: &[Config], at: usize) -> Vec<Config> {
    let Some(level) = levels.get(at) else {
        return Vec::new();
    };
    let with = |c: &Config, element: Element, nu: f64| {
        let mut c = c.clone();
        c.element = element;
        c.nu = nu;
        c.sweep = "incompressible".into();
        c.labelled()
    };
    let mut out = Vec::new();
    for element in [Element::Tet4, Element::Tet4NodalPressure] {
        for nu in NUS {
            if !(element == Element::Tet4NodalPressure && nu == 0.45) {
                out.push(with(level, element, nu));
            }
        }
    }
    for (i, c) in levels.iter().enumerate() {
        if i != at {
            out.push(with(c, Element::Tet4NodalPressure, NU_LIMIT));
        }
    }
    out
}

/// One element's values on the sweep level.
#[derive(Debug, Clone, Serialize)]
pub struct ElementSweep {
    /// The element.
    pub element: String,
    /// Per `nu` of [`NUS`]: `F`, N (both spatulas' final net force
    /// magnitudes summed), `None` when the run is missing.
    pub force_n: Vec<Option<f64>>,
    /// Per `nu`: `R(nu) = F(nu) / F(0.45)`.
    pub ratio: Vec<Option<f64>>,
    /// Per `nu`: failed solver steps.
    pub failed_steps: Vec<Option<usize>>,
}

/// The sweep's result.
#[derive(Debug, Clone, Serialize)]
pub struct Incompressible {
    /// [`NUS`].
    pub nus: Vec<f64>,
    /// The sweep level's label at `nu` = 0.45 with the nodal-pressure
    /// element.
    pub level: String,
    /// `tet4`, then `tet4-nodal-pressure`, on the sweep level.
    pub elements: Vec<ElementSweep>,
    /// The nodal-pressure `R(0.4999)` per convergence level (coarsest
    /// first): label, element size (mm), ratio.
    pub limit_by_level: Vec<(String, f64, f64)>,
    /// Its Richardson estimate over the last three levels.
    pub richardson: Option<Richardson>,
    /// The converged answer: the Richardson limit, or the finest level's
    /// value when the levels are not in the asymptotic range.
    pub converged_ratio: Option<f64>,
    /// Deviation of each element's sweep-level `R(0.4999)` from it, %
    /// (`tet4`, `tet4-nodal-pressure`).
    pub deviation_pct: [Option<f64>; 2],
    /// [`TOLERANCE_PCT`].
    pub tolerance_pct: f64,
    /// Whether the nodal-pressure deviation is within the tolerance.
    pub met: bool,
}

fn total_force_n(r: &RunResult) -> f64 {
    r.final_force(0).norm() + r.final_force(1).norm()
}

fn same_level(a: &Config, b: &Config) -> bool {
    convergence::same_shape(a, b) && a.refine == b.refine && a.refine_near_m == b.refine_near_m
}

/// Evaluates the sweep on the level `at` (its configuration) from the
/// convergence levels' runs (coarsest first) and the sweep's own runs.
pub fn evaluate(levels: &[&RunResult], at: &Config, runs: &[&RunResult]) -> Option<Incompressible> {
    let level = *levels.iter().find(|l| same_level(&l.config, at))?;
    let all: Vec<&RunResult> = levels.iter().chain(runs).copied().collect();
    let find = |level: &Config, element: Element, nu: f64| {
        all.iter()
            .find(|r| {
                same_level(&r.config, level) && r.config.element == element && r.config.nu == nu
            })
            .copied()
    };
    let elements: Vec<ElementSweep> = [Element::Tet4, Element::Tet4NodalPressure]
        .into_iter()
        .map(|element| {
            let rs: Vec<Option<&RunResult>> = NUS
                .iter()
                .map(|&nu| find(&level.config, element, nu))
                .collect();
            let force_n: Vec<Option<f64>> = rs.iter().map(|r| r.map(total_force_n)).collect();
            let ratio = force_n
                .iter()
                .map(|f| Some(f.as_ref()? / force_n[0]?))
                .collect();
            ElementSweep {
                element: element.name().into(),
                force_n,
                ratio,
                failed_steps: rs.iter().map(|r| r.map(|r| r.failed_steps)).collect(),
            }
        })
        .collect();
    let limit_by_level: Vec<(String, f64, f64)> = levels
        .iter()
        .filter_map(|l| {
            let np = Element::Tet4NodalPressure;
            let f0 = total_force_n(find(&l.config, np, NUS[0])?);
            let f = total_force_n(find(&l.config, np, NU_LIMIT)?);
            Some((
                l.config.label.clone(),
                convergence::level_size_mm(l),
                f / f0,
            ))
        })
        .collect();
    let richardson = (limit_by_level.len() >= 3).then(|| {
        let l = &limit_by_level[limit_by_level.len() - 3..];
        convergence::richardson([l[0].1, l[1].1, l[2].1], [l[0].2, l[1].2, l[2].2])
    });
    let converged_ratio = match richardson {
        Some(Richardson::Asymptotic { limit, .. }) => Some(limit),
        _ => limit_by_level.last().map(|l| l.2),
    };
    let last = NUS.len() - 1;
    let deviation_pct = [0, 1].map(|e| {
        let r = elements[e].ratio[last]?;
        let c = converged_ratio?;
        Some(100.0 * (r - c).abs() / c)
    });
    Some(Incompressible {
        nus: NUS.to_vec(),
        level: level.config.label.clone(),
        met: deviation_pct[1].is_some_and(|d| d <= TOLERANCE_PCT),
        elements,
        limit_by_level,
        richardson,
        converged_ratio,
        deviation_pct,
        tolerance_pct: TOLERANCE_PCT,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sweep_adds_only_the_runs_the_levels_lack() {
        let levels = convergence::levels(&Config::baseline());
        let runs = configs(&levels, convergence::SWEEP_LEVEL);
        // 4 nu with tet4 and 3 with nodal pressure on 204k, and the limit
        // on the 4 other levels.
        assert_eq!(runs.len(), 11);
        for c in &runs {
            assert!(!levels.contains(c), "{} duplicates a level", c.label);
            assert_eq!(runs.iter().filter(|o| o.label == c.label).count(), 1);
        }
        assert!(
            runs.iter()
                .any(|c| c.label == "204k/lin/n150/nu0.4999/foundation")
        );
        assert!(
            runs.iter()
                .any(|c| c.label == "34k/lin/n150/nu0.4999/np/foundation")
        );
    }
}
