//! Mesh convergence of the reference: the reference physics (frictionless
//! contact, the scene's elastic foundation, the `tet4-nodal-pressure`
//! element) on successively finer meshes, coarsest first ([`LEVELS`]):
//! paper-34k, paper-48k, then paper-48k meshed by the proven mesher at a
//! 4 mm (the 204k level), 3.6 mm and 3.2 mm spacing.
//!
//! **One shape refined** ([`refined`]): each of the product's two meshes
//! (paper-34k, paper-48k) also with its uniform refinements
//! ([`fissure_engine::mesh::refine`]: each tetrahedron into eight at its
//! edge midpoints, the surface kept exactly), a family of its own in which
//! only `h` changes, halved at each refinement. The mesher's levels above
//! do not share one shape (each lattice snaps onto the surface anew: their
//! rest surfaces near the fissure lie 0.1 to 0.3 mm apart), so only these
//! families separate the discretisation's share of the force from the
//! geometry's. The study's reference is paper-48k refined once
//! ([`REFERENCE_REFINEMENTS`]): the product's own shape, about 8 times
//! finer.
//!
//! The material law is linear elasticity, solved by `compliance` (the
//! supported stiffness factored once, the contact condensed exactly onto
//! the contact nodes' columns of its inverse; `direct`, the independent
//! check, costs 13x a step with the nodal-pressure element, DESIGN.md).
//! `neo-hookean` takes the foundation and the nodal-pressure element too,
//! but refactors its tangent at every Newton iteration: on these levels a
//! run would cost many times the linear one, so the grid measures the
//! material law's share at paper-48k instead.
//!
//! Per level: the net force on each spatula at the last step and its peak
//! over the steps. Between successive levels: the force change relative to
//! the finer level, and the surface displacement difference over the error
//! region of the finer level ([`compare`](super::compare): the finer level
//! plays the reference, the coarser is mapped onto it by nearest point).
//! The criterion: the final net force changes by under
//! [`FORCE_CRITERION_PCT`] between the last two levels, on both spatulas.
//!
//! **Element size.** The levels are not all one mesh family refined by a
//! fixed ratio (the first two differ in grading and mesher from the
//! proven ones), so each level's size is the one number they share: `h = (V / n)^(1/3)`, the edge of the cube of a
//! tetrahedron's mean volume, with `V` the volume enclosed by the rest
//! surface ([`enclosed_volume`], divergence theorem: `V = sum over
//! triangles (a . (b x c)) / 6`) and `n` the tetrahedron count.
//!
//! **Richardson extrapolation** ([`richardson`]) over the last three
//! levels (the proven family). With `F(h) = F_inf + C h^p` and three levels
//! `h0 > h1 > h2`, the order solves
//! `(F0 - F1) / (F1 - F2) = (h0^p - h1^p) / (h1^p - h2^p)` (bisection: the
//! right side increases with `p` from `ln(h0/h1) / ln(h1/h2)` at `p -> 0`);
//! then `C = (F1 - F2) / (h1^p - h2^p)` and `F_inf = F2 - C h2^p`. When the
//! changes differ in sign (not monotone), the ratio is below the `p -> 0`
//! bound (changes not shrinking fast enough for any positive order), or the
//! order exceeds [`MAX_ORDER`], the levels are not in the asymptotic range
//! and no limit is given.
//!
//! **Two-level estimates** ([`extrapolate`]): with an assumed order `p`,
//! the last two levels give `F_inf = F2 + (F2 - F1) / ((h1 / h2)^p - 1)`;
//! the report gives them for `p = 1` and `p = 2` (the orders P1 elements
//! reach for reactions and displacements), a bracket of the finest level's
//! discretisation error when the three-level order is not usable.

use super::compare;
use super::config::{Config, Support};
use super::driver::RunResult;
use fissure_engine::fem::{Element, Strategy};
use fissure_engine::mesh::enclosed_volume;
use fissure_engine::scene::ContactLaw;
use serde::Serialize;

/// Largest change of the final net force between the last two levels for
/// the reference to count as converged, %.
pub const FORCE_CRITERION_PCT: f64 = 1.0;

/// Largest observed order accepted as asymptotic: P1 tetrahedra converge
/// displacements at `O(h^2)` and reactions at `O(h)` to `O(h^2)`; an order
/// above twice the displacement order says the levels differ in more than
/// `h` (grading, mesher), not that they converge that fast.
pub const MAX_ORDER: f64 = 4.0;

/// The assumed orders of the two-level estimates.
pub const ASSUMED_ORDERS: [f64; 2] = [1.0, 2.0];

/// Relative residual tolerance the reference's configuration names (the
/// linear `compliance` strategy solves directly and does not read it).
pub const REFERENCE_TOLERANCE: f64 = 1e-9;

/// Sets the reference physics on `c`: frictionless contact, the scene's
/// foundation, the nodal-pressure element, linear elasticity solved by
/// `compliance`.
pub fn reference_physics(c: &mut Config) {
    c.strategy = Strategy::Compliance;
    c.element = Element::Tet4NodalPressure;
    c.tolerance = REFERENCE_TOLERANCE;
    c.contact_law = ContactLaw::Frictionless;
    c.support = Support::Foundation;
}

/// The mesh of each convergence level, coarsest first: (preset, proven
/// mesher, finest lattice spacing in m or the preset's). paper-34k and
/// paper-48k are the product's graded meshes; then one family of the
/// proven mesher (the whole surface at the spacing, the interior graded
/// alike) at 4 mm (the 204k level), 3.6 mm (269k) and 3.2 mm (353k), over
/// which Richardson's order is meaningful. A coarser member does not
/// belong to it: at 5 mm the lattice no longer resolves the 3 mm fissure
/// (the mesher repairs pinched edges in it) and the spatulas meet another
/// wall.
pub const LEVELS: [(&str, bool, Option<f64>); 5] = [
    ("paper-34k", false, None),
    ("paper-48k", false, None),
    ("paper-48k", true, None),
    ("paper-48k", true, Some(0.0036)),
    ("paper-48k", true, Some(0.0032)),
];

/// The index in [`LEVELS`] of the 204k level, where the incompressibility
/// sweep and the finest-mesh extremes run (on the finer levels each run
/// costs about four times as much, and the sweep has seven).
pub const SWEEP_LEVEL: usize = 2;

/// The indices in [`LEVELS`] of the product's meshes, refined uniformly in
/// the one-shape families ([`refined`]).
pub const REFINED_LEVELS: [usize; 2] = [0, 1];

/// The uniform refinements planned by default per family: one (paper-48k
/// refined once has 402k tetrahedra and 83k nodes and peaks at 16 GB;
/// twice, 3.2 M and about 650k, needs a larger machine).
pub const DEFAULT_REFINEMENTS: u32 = 1;

/// The reference: paper-48k ([`LEVELS`]`[1]`) refined this many times.
pub const REFERENCE_REFINEMENTS: u32 = 1;

/// The one-shape families of the full study around `base`: each of
/// [`REFINED_LEVELS`] refined `1..=refinements` times, coarsest first
/// within each family.
pub fn refined(base: &Config, refinements: u32) -> Vec<Config> {
    let levels = levels(base);
    REFINED_LEVELS
        .iter()
        .flat_map(|&i| {
            let level = levels[i].clone();
            (1..=refinements).map(move |r| {
                Config {
                    refine: r,
                    ..level.clone()
                }
                .labelled()
            })
        })
        .collect()
}

/// The study's reference around `base`: paper-48k refined
/// [`REFERENCE_REFINEMENTS`] times, with the reference physics.
pub fn reference(base: &Config) -> Config {
    Config {
        refine: REFERENCE_REFINEMENTS,
        sweep: "reference".into(),
        ..levels(base)[1].clone()
    }
    .labelled()
}

/// Whether `a` and `b` mesh the same shape the same way (preset, mesher,
/// spacing), whatever the refinements.
pub fn same_shape(a: &Config, b: &Config) -> bool {
    a.preset == b.preset && a.proven == b.proven && a.spacing_m == b.spacing_m
}

/// The convergence levels of the full study around `base`, coarsest first
/// ([`LEVELS`]).
pub fn levels(base: &Config) -> Vec<Config> {
    LEVELS
        .into_iter()
        .map(|(preset, proven, spacing_m)| {
            let mut c = base.clone();
            reference_physics(&mut c);
            c.preset = preset.into();
            c.proven = proven;
            c.spacing_m = spacing_m;
            c.sweep = "convergence".into();
            c.labelled()
        })
        .collect()
}

/// Characteristic element size `h = (V / n)^(1/3)`, m, of `tets`
/// tetrahedra filling `volume_m3`.
pub fn element_size_m(volume_m3: f64, tets: usize) -> f64 {
    (volume_m3 / tets.max(1) as f64).cbrt()
}

/// The characteristic element size of a run's mesh, mm
/// ([`element_size_m`] of the volume its rest surface encloses).
pub fn level_size_mm(run: &RunResult) -> f64 {
    let volume = enclosed_volume(&run.rest_surface, &run.triangles).abs();
    element_size_m(volume, run.tets) * 1e3
}

/// The Richardson estimate from three levels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "status", rename_all = "kebab-case")]
pub enum Richardson {
    /// Monotone changes consistent with a positive order.
    Asymptotic {
        /// Observed order `p`.
        order: f64,
        /// Extrapolated value `F_inf` (the quantity's unit: N here).
        limit: f64,
        /// `|F2 - F_inf| / |F_inf|` of the finest level, %.
        finest_error_pct: f64,
    },
    /// The changes are not monotone, shrink too slowly for any positive
    /// order, or give an order above [`MAX_ORDER`]: not in the asymptotic
    /// range.
    NotAsymptotic {
        /// `(F0 - F1) / (F1 - F2)`.
        change_ratio: f64,
        /// The order those changes would give, when one exists.
        order: Option<f64>,
    },
}

/// The limit `F2 + (F2 - F1) / ((h1 / h2)^p - 1)` of `f = [F1, F2]` at
/// sizes `h = [h1, h2]` (`h1 > h2`) for an assumed order `p`.
pub fn extrapolate(h: [f64; 2], f: [f64; 2], p: f64) -> f64 {
    f[1] + (f[1] - f[0]) / ((h[0] / h[1]).powf(p) - 1.0)
}

/// Richardson extrapolation of `f` measured at sizes `h` (coarsest first,
/// `h[0] > h[1] > h[2] > 0`), see the module's documentation.
pub fn richardson(h: [f64; 3], f: [f64; 3]) -> Richardson {
    let (d01, d12) = (f[0] - f[1], f[1] - f[2]);
    let change_ratio = d01 / d12;
    let not = Richardson::NotAsymptotic {
        change_ratio,
        order: None,
    };
    if !(change_ratio.is_finite() && change_ratio > 0.0 && h[0] > h[1] && h[1] > h[2]) {
        return not;
    }
    let g = |p: f64| (h[0].powf(p) - h[1].powf(p)) / (h[1].powf(p) - h[2].powf(p));
    let floor = (h[0] / h[1]).ln() / (h[1] / h[2]).ln();
    let (mut lo, mut hi) = (1e-6_f64, 30.0_f64);
    if change_ratio <= floor || g(hi) < change_ratio {
        return not;
    }
    for _ in 0..200 {
        let mid = (lo * hi).sqrt();
        if g(mid) < change_ratio {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let p = 0.5 * (lo + hi);
    if p > MAX_ORDER {
        return Richardson::NotAsymptotic {
            change_ratio,
            order: Some(p),
        };
    }
    let c = d12 / (h[1].powf(p) - h[2].powf(p));
    let limit = f[2] - c * h[2].powf(p);
    Richardson::Asymptotic {
        order: p,
        limit,
        finest_error_pct: 100.0 * (f[2] - limit).abs() / limit.abs(),
    }
}

/// One mesh level.
#[derive(Debug, Clone, Serialize)]
pub struct Level {
    /// The configuration's label.
    pub label: String,
    /// Tetrahedra.
    pub tets: usize,
    /// Nodes.
    pub nodes: usize,
    /// Characteristic element size `(V / n)^(1/3)`, mm.
    pub h_mm: f64,
    /// Net force on each spatula at the last step, N.
    pub final_force_n: [f64; 2],
    /// Largest net force on each spatula over the steps, N.
    pub peak_force_n: [f64; 2],
    /// Mean time per deformation step, ms.
    pub ms_per_step: f64,
    /// Mean solver iterations a step.
    pub iterations_mean: f64,
    /// Failed steps.
    pub failed_steps: usize,
}

/// From one level to the next finer one.
#[derive(Debug, Clone, Serialize)]
pub struct Change {
    /// The coarser level's label.
    pub from: String,
    /// The finer level's label.
    pub to: String,
    /// `|F_fine - F_coarse| / F_fine` of the final net force, per spatula, %.
    pub final_force_change_pct: [f64; 2],
    /// The same of the peak net force, %.
    pub peak_force_change_pct: [f64; 2],
    /// Displacement difference over the finer level's error region and all
    /// steps: RMS, mm.
    pub rms_mm: f64,
    /// Its maximum, mm.
    pub max_mm: f64,
    /// Largest displacement of the finer level in the region, mm.
    pub ref_max_mm: f64,
    /// How far the two rest surfaces lie apart over the region (each
    /// finer-level point to the coarser surface's nearest point): RMS, mm.
    /// The levels mesh one shape, each at its own resolution, so this is
    /// the geometry's own discretisation change.
    pub rest_rms_mm: f64,
    /// Its maximum, mm.
    pub rest_max_mm: f64,
    /// Region points compared.
    pub points: usize,
}

/// The two-level estimate for one assumed order.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct TwoLevel {
    /// The assumed order `p`.
    pub order: f64,
    /// Extrapolated final net force per spatula, N.
    pub limit_n: [f64; 2],
    /// The finest level's final net force from it, per spatula, %.
    pub finest_error_pct: [f64; 2],
}

/// The convergence of the reference over the levels.
#[derive(Debug, Clone, Serialize)]
pub struct Convergence {
    /// The levels, coarsest first.
    pub levels: Vec<Level>,
    /// Successive changes.
    pub changes: Vec<Change>,
    /// Richardson estimate of the final net force per spatula (the last
    /// three levels), when there are three.
    pub richardson_final: Option<[Richardson; 2]>,
    /// The same of the peak net force.
    pub richardson_peak: Option<[Richardson; 2]>,
    /// Two-level estimates of the final net force from the last two levels,
    /// one per [`ASSUMED_ORDERS`].
    pub two_level: Vec<TwoLevel>,
    /// [`FORCE_CRITERION_PCT`].
    pub criterion_pct: f64,
    /// Whether the final net force of both spatulas changes by under the
    /// criterion between the last two levels.
    pub met: bool,
    /// The one-shape families ([`refined`]): each a level and its uniform
    /// refinements, evaluated alike (their own `refined` is empty).
    pub refined: Vec<Convergence>,
}

fn peak(run: &RunResult, i: usize) -> f64 {
    run.step_force
        .iter()
        .filter_map(|f| f.get(i))
        .map(|v| v.norm())
        .fold(0.0, f64::max)
}

fn change_pct(coarse: f64, fine: f64) -> f64 {
    100.0 * (fine - coarse).abs() / fine.abs().max(f64::MIN_POSITIVE)
}

/// Evaluates the runs of the levels, coarsest first.
pub fn evaluate(runs: &[&RunResult]) -> Convergence {
    let levels: Vec<Level> = runs
        .iter()
        .map(|r| Level {
            label: r.config.label.clone(),
            tets: r.tets,
            nodes: r.nodes,
            h_mm: level_size_mm(r),
            final_force_n: [r.final_force(0).norm(), r.final_force(1).norm()],
            peak_force_n: [peak(r, 0), peak(r, 1)],
            ms_per_step: r.ms_per_step(),
            iterations_mean: r.mean_iterations(),
            failed_steps: r.failed_steps,
        })
        .collect();
    let changes: Vec<Change> = runs
        .windows(2)
        .zip(levels.windows(2))
        .map(|(r, l)| {
            let (coarse, fine) = (r[0], r[1]);
            let region = compare::region_vertices(fine);
            let e = compare::compare(fine, &region, coarse);
            Change {
                from: l[0].label.clone(),
                to: l[1].label.clone(),
                final_force_change_pct: [0, 1]
                    .map(|i| change_pct(l[0].final_force_n[i], l[1].final_force_n[i])),
                peak_force_change_pct: [0, 1]
                    .map(|i| change_pct(l[0].peak_force_n[i], l[1].peak_force_n[i])),
                rms_mm: e.rms_mm,
                max_mm: e.max_mm,
                ref_max_mm: e.ref_max_mm,
                rest_rms_mm: e.rms_match_mm,
                rest_max_mm: e.max_match_mm,
                points: e.points,
            }
        })
        .collect();
    let last3 = levels.len().checked_sub(3).map(|s| &levels[s..]);
    let rich = |pick: fn(&Level) -> [f64; 2]| {
        last3.map(|l| {
            let h = [l[0].h_mm, l[1].h_mm, l[2].h_mm];
            [0, 1].map(|i| richardson(h, [pick(&l[0])[i], pick(&l[1])[i], pick(&l[2])[i]]))
        })
    };
    let met = changes.last().is_some_and(|c| {
        c.final_force_change_pct
            .iter()
            .all(|&p| p < FORCE_CRITERION_PCT)
    });
    let two_level = match levels.len().checked_sub(2).map(|s| &levels[s..]) {
        Some([a, b]) => ASSUMED_ORDERS
            .iter()
            .map(|&p| {
                let limit_n = [0, 1].map(|i| {
                    extrapolate(
                        [a.h_mm, b.h_mm],
                        [a.final_force_n[i], b.final_force_n[i]],
                        p,
                    )
                });
                TwoLevel {
                    order: p,
                    limit_n,
                    finest_error_pct: [0, 1].map(|i| change_pct(b.final_force_n[i], limit_n[i])),
                }
            })
            .collect(),
        _ => Vec::new(),
    };
    Convergence {
        two_level,
        richardson_final: rich(|l| l.final_force_n),
        richardson_peak: rich(|l| l.peak_force_n),
        levels,
        changes,
        criterion_pct: FORCE_CRITERION_PCT,
        met,
        refined: Vec::new(),
    }
}

/// The one-shape families among `runs` (levels and refinements, in any
/// order): each unrefined run with the uniform refinements of its shape,
/// coarsest first; a family needs its unrefined level and one refinement.
/// Locally refined runs (`refine_near_m`) belong to none.
pub fn families<'a>(runs: &[&'a RunResult]) -> Vec<Vec<&'a RunResult>> {
    let uniform = |r: &RunResult| r.config.refine_near_m.is_empty();
    let mut out = Vec::new();
    for base in runs.iter().filter(|r| r.config.refine == 0 && uniform(r)) {
        let mut family: Vec<&RunResult> = runs
            .iter()
            .filter(|r| r.config.refine > 0 && uniform(r) && same_shape(&r.config, &base.config))
            .copied()
            .collect();
        if family.is_empty() {
            continue;
        }
        family.sort_by_key(|r| r.config.refine);
        family.dedup_by_key(|r| r.config.refine);
        family.insert(0, base);
        out.push(family);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn richardson_recovers_the_order_and_the_limit_of_a_power_law() {
        // Uniform ratio 2, p = 2.
        let f = |h: f64| 0.125 + 0.3 * h * h;
        let h = [4.0, 2.0, 1.0];
        match richardson(h, h.map(f)) {
            Richardson::Asymptotic {
                order,
                limit,
                finest_error_pct,
            } => {
                assert!((order - 2.0).abs() < 1e-9, "order {order}");
                assert!((limit - 0.125).abs() < 1e-12, "limit {limit}");
                assert!((finest_error_pct - 240.0).abs() < 1e-6);
            }
            r => panic!("{r:?}"),
        }
        // Uneven sizes (as the study's levels), p = 1.3, decreasing towards
        // the limit.
        let f = |h: f64| 0.07 - 0.004 * h.powf(1.3);
        let h = [4.9, 4.6, 2.8];
        match richardson(h, h.map(f)) {
            Richardson::Asymptotic { order, limit, .. } => {
                assert!((order - 1.3).abs() < 1e-7, "order {order}");
                assert!((limit - 0.07).abs() < 1e-10, "limit {limit}");
            }
            r => panic!("{r:?}"),
        }
    }

    #[test]
    fn two_level_extrapolation_is_exact_for_the_assumed_order() {
        let f = |h: f64| 0.11 + 0.002 * h.powi(2);
        let h = [2.85, 1.79];
        let limit = extrapolate(h, h.map(f), 2.0);
        assert!((limit - 0.11).abs() < 1e-14, "{limit}");
        // The wrong order misses it.
        assert!((extrapolate(h, h.map(f), 1.0) - 0.11).abs() > 1e-3);
    }

    #[test]
    fn richardson_refuses_non_monotone_or_stalling_sequences() {
        // The changes differ in sign.
        assert!(matches!(
            richardson([4.0, 2.0, 1.0], [1.0, 1.2, 1.1]),
            Richardson::NotAsymptotic { .. }
        ));
        // Growing changes on halving sizes: no positive order (the p -> 0
        // bound of the ratio is 1).
        assert!(matches!(
            richardson([4.0, 2.0, 1.0], [1.0, 1.1, 1.25]),
            Richardson::NotAsymptotic { change_ratio, order: None } if (change_ratio - 2.0 / 3.0).abs() < 1e-9
        ));
        // Changes shrinking by 2^10 on halving sizes: order 10, above
        // MAX_ORDER.
        assert!(matches!(
            richardson([4.0, 2.0, 1.0], [1.0, 1.0 + 1024e-6, 1.0 + 1025e-6]),
            Richardson::NotAsymptotic { order: Some(p), .. } if (p - 10.0).abs() < 1e-6
        ));
        // No change at the last level: the ratio is infinite.
        assert!(matches!(
            richardson([4.0, 2.0, 1.0], [1.0, 1.1, 1.1]),
            Richardson::NotAsymptotic { .. }
        ));
    }

    #[test]
    fn the_element_size_of_a_meshed_cube_is_its_mean_tetrahedron_volume_cubed_root() {
        let cube = fissure_engine::mesh::blocks::cube(0.04, 4);
        let surf = cube.boundary();
        let mut pos = Vec::new();
        surf.gather(&cube.nodes, &mut pos);
        let v = enclosed_volume(&pos, &surf.triangles).abs();
        assert!((v - 0.04f64.powi(3)).abs() < 1e-15, "volume {v}");
        let h = element_size_m(v, cube.tets.len());
        let mean = (0..cube.tets.len())
            .map(|t| cube.signed_volume(t).abs())
            .sum::<f64>()
            / cube.tets.len() as f64;
        assert!((h.powi(3) - mean).abs() < 1e-18, "h {h}");
    }

    #[test]
    fn one_shape_families_gather_each_level_with_its_refinements_coarsest_first() {
        let levels = levels(&Config::baseline());
        let run = |c: &Config| RunResult {
            config: c.clone(),
            ..compare::at_rest(Vec::new(), Vec::new())
        };
        let refined = refined(&Config::baseline(), 2);
        let reference = reference(&Config::baseline());
        // In plan order, the reference first (as the merge finds it), the
        // 204k level without refinements, 48k-r2 before 48k.
        let runs: Vec<RunResult> = [
            &reference,
            &levels[0],
            &levels[SWEEP_LEVEL],
            &refined[3],
            &refined[1],
            &refined[0],
            &levels[1],
        ]
        .into_iter()
        .map(run)
        .collect();
        let refs: Vec<&RunResult> = runs.iter().collect();
        let labels: Vec<Vec<&str>> = families(&refs)
            .iter()
            .map(|f| f.iter().map(|r| r.config.label.as_str()).collect())
            .collect();
        assert_eq!(
            labels,
            [
                vec![
                    "34k/lin/n150/np/foundation",
                    "34k-r1/lin/n150/np/foundation",
                    "34k-r2/lin/n150/np/foundation"
                ],
                vec![
                    "48k/lin/n150/np/foundation",
                    "48k-r1/lin/n150/np/foundation",
                    "48k-r2/lin/n150/np/foundation"
                ],
            ]
        );
        // A level without its unrefined run makes no family.
        let lone: Vec<&RunResult> = vec![&runs[3]];
        assert!(families(&lone).is_empty());
        // A locally refined run is neither a family's base nor a member.
        let near = run(&Config {
            refine_near_m: vec![0.02],
            ..levels[1].clone()
        });
        let near_r1 = run(&Config {
            refine_near_m: vec![0.02],
            ..refined[2].clone()
        });
        let mut with_near = refs.clone();
        with_near.extend([&near, &near_r1]);
        assert_eq!(families(&with_near).len(), 2);
        assert!(
            families(&with_near)
                .iter()
                .flatten()
                .all(|r| r.config.refine_near_m.is_empty())
        );
        // The reference is the product's shape refined once, with the
        // reference physics.
        assert_eq!(reference.label, "48k-r1/lin/n150/np/foundation");
        assert!(same_shape(&reference, &levels[1]) && !same_shape(&reference, &levels[2]));
    }

    #[test]
    fn the_levels_carry_the_reference_physics_and_distinct_labels() {
        let levels = levels(&Config::baseline());
        let labels: Vec<&str> = levels.iter().map(|c| c.label.as_str()).collect();
        assert_eq!(
            labels,
            [
                "34k/lin/n150/np/foundation",
                "48k/lin/n150/np/foundation",
                "204k/lin/n150/np/foundation",
                "48k-proven-3.6mm/lin/n150/np/foundation",
                "48k-proven-3.2mm/lin/n150/np/foundation",
            ]
        );
        assert_eq!(labels[SWEEP_LEVEL], "204k/lin/n150/np/foundation");
        let scene = levels[SWEEP_LEVEL].scene().expect("the 204k level's scene");
        assert!(scene.foundation.is_some());
        let finest = levels[4].scene().expect("the finest level's scene");
        assert!(matches!(
            finest.model,
            fissure_engine::scene::ModelSpec::Phantom {
                proven: true,
                spacing_m: Some(h),
                ..
            } if h == 0.0032
        ));
        assert!(Config::baseline().scene().unwrap().foundation.is_none());
    }
}
