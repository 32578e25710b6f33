//! Deformation-step benchmark: time per step of each FEM strategy on a mesh
//! with a growing contact set (surface vertices nearest the top centre,
//! indented along -z), bottom nodes fixed.
//!
//! Each (strategy, contact count) runs one untimed warm-up step (it caches
//! the compliance columns of the new contact nodes) and then `steps` timed
//! steps at increasing indentation depth; `ms_per_step` is their mean.
//! Every strategy runs with each element formulation asked for (`tet4`,
//! `tet4-nodal-pressure`; `corotational` with `tet4` only), side by side
//! in one run.
//!
//! Supports ([`Support`]): the fixed bottom alone (`stem`), and with
//! `--foundation-pa-per-m K` also an elastic foundation of `K` on every
//! outer triangle farther than [`FOUNDATION_OPEN_M`] from the top centre
//! (the craniotomy window the contact set lies in), as the bundled scenes
//! hold the brain. The two run on the same contact set, one solver each,
//! their timed steps alternating (so that a change in the machine's load
//! falls on both alike): their ratio ([`Row::over_stem`]) is the
//! foundation's own cost per step, apart from the larger contact set a
//! held brain leads to in a scene.

use fissure_engine::fem::compliance::Recover;
use fissure_engine::fem::foundation::{Foundation, outer_faces_where};
use fissure_engine::fem::{
    Element, Material, Par, Prescribed, SolverOptions, Strategy, build_solver,
};
use fissure_engine::mesh::TetMesh;
use nalgebra::{Point3, Vector3};
use serde::Serialize;
use std::time::Instant;

/// Options of [`run_fem_bench`].
#[derive(Debug, Clone)]
pub struct FemBenchOptions {
    /// Strategies to time.
    pub strategies: Vec<Strategy>,
    /// Contact-set sizes (surface vertices).
    pub contact_counts: Vec<usize>,
    /// Timed steps per (strategy, contact count); `neo-hookean` runs at most 2.
    pub steps: usize,
    /// Material.
    pub material: Material,
    /// Deepest indentation, m.
    pub depth_m: f64,
    /// Recovery of `compliance` (the benchmark also reports `Surface`).
    pub compliance_surface_too: bool,
    /// Parallelism given to the solvers (default: every rayon thread).
    pub parallelism: Par,
    /// Element formulations (`corotational` takes `tet4` only).
    pub elements: Vec<Element>,
    /// Supports, side by side.
    pub supports: Vec<Support>,
}

/// How the benchmark's mesh is held.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Support {
    /// The bottom nodes fixed (2 % of the height), as the brain stem.
    Stem,
    /// The bottom fixed and an elastic foundation of this stiffness, Pa/m,
    /// on the outer triangles away from the top ([`FOUNDATION_OPEN_M`]).
    Foundation {
        /// Normal stiffness per area, Pa/m.
        stiffness_pa_per_m: f64,
    },
}

impl Support {
    /// The row label.
    pub fn label(self) -> String {
        match self {
            Self::Stem => "stem".into(),
            Self::Foundation { stiffness_pa_per_m } => {
                format!("foundation {stiffness_pa_per_m:.3e} Pa/m")
            }
        }
    }
}

/// Radius of the foundation's opening about the top centre, m (the bundled
/// scenes open a 25 mm sphere about the fissure's entry).
pub const FOUNDATION_OPEN_M: f64 = 0.025;

impl Default for FemBenchOptions {
    fn default() -> Self {
        Self {
            strategies: Strategy::ALL.to_vec(),
            contact_counts: vec![10, 50, 200],
            steps: 5,
            material: Material {
                youngs_modulus_pa: 3000.0,
                poisson_ratio: 0.45,
            },
            depth_m: 1e-3,
            compliance_surface_too: true,
            parallelism: Par::rayon(0),
            elements: Element::ALL.to_vec(),
            supports: vec![Support::Stem],
        }
    }
}

/// One benchmark row.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Row {
    /// Mesh preset name.
    pub preset: String,
    /// Tetrahedra.
    pub tets: usize,
    /// Nodes.
    pub nodes: usize,
    /// Strategy name (`compliance-surface` for surface-only recovery).
    pub strategy: String,
    /// Element formulation.
    pub element: String,
    /// Support ([`Support::label`]).
    pub support: String,
    /// Contact vertices.
    pub contact_vertices: usize,
    /// Mean time per timed step, ms.
    pub ms_per_step: f64,
    /// `ms_per_step` over the same row's on the stem alone (the same
    /// strategy, element and contact set): the support's own cost; `None`
    /// on the stem's rows.
    pub over_stem: Option<f64>,
    /// The untimed warm-up step (new contact columns), ms.
    pub first_step_ms: f64,
    /// Building the solver (assembly, factorization), ms.
    pub setup_ms: f64,
    /// Mean solver iterations per step.
    pub iterations: f64,
    /// Timed steps.
    pub steps: usize,
    /// Threads the solver was given (1: sequential).
    pub threads: usize,
    /// Error message when a step failed.
    pub error: Option<String>,
}

/// Runs the benchmark on `mesh`, labelled `preset_name`.
pub fn run_fem_bench(mesh: &TetMesh, preset_name: &str, opts: &FemBenchOptions) -> Vec<Row> {
    let (lo, hi) = mesh.bounds();
    let zcut = lo.z + 0.02 * (hi.z - lo.z);
    let fixed: Vec<u32> = (0..mesh.nodes.len() as u32)
        .filter(|&i| mesh.nodes[i as usize].z <= zcut)
        .collect();
    let top = Point3::new(0.5 * (lo.x + hi.x), 0.5 * (lo.y + hi.y), hi.z);
    let mut surface = mesh.boundary().to_volume;
    surface.retain(|&n| mesh.nodes[n as usize].z > zcut);
    surface.sort_by(|&a, &b| {
        let da = (mesh.nodes[a as usize] - top).norm();
        let db = (mesh.nodes[b as usize] - top).norm();
        da.total_cmp(&db).then(a.cmp(&b))
    });
    let open_faces = foundation_faces(mesh, top, FOUNDATION_OPEN_M);
    let mut variants: Vec<(Strategy, Element, Recover, String)> = Vec::new();
    for &s in &opts.strategies {
        for &e in &opts.elements {
            if !s.takes_element(e) {
                continue;
            }
            variants.push((s, e, Recover::All, s.name().to_string()));
            if s == Strategy::Compliance && opts.compliance_surface_too {
                variants.push((s, e, Recover::Surface, "compliance-surface".into()));
            }
        }
    }
    let row = |label: &str, element: Element, support: Support| Row {
        preset: preset_name.into(),
        tets: mesh.tets.len(),
        nodes: mesh.nodes.len(),
        strategy: label.into(),
        element: element.name().into(),
        support: support.label(),
        contact_vertices: 0,
        ms_per_step: f64::NAN,
        over_stem: None,
        first_step_ms: f64::NAN,
        setup_ms: f64::NAN,
        iterations: 0.0,
        steps: 0,
        threads: opts.parallelism.degree(),
        error: None,
    };
    let mut rows = Vec::new();
    for (strategy, element, recover, label) in variants {
        // One solver per support; their timed steps alternate, so that a
        // change in the machine's load falls on every support alike.
        let mut solvers = Vec::new();
        for &support in &opts.supports {
            let foundation = match support {
                Support::Stem => None,
                Support::Foundation { stiffness_pa_per_m } => Some(Foundation {
                    stiffness_pa_per_m,
                    faces: open_faces.clone(),
                }),
            };
            let t0 = Instant::now();
            let solver = build_solver(
                strategy,
                mesh,
                opts.material,
                &fixed,
                &SolverOptions {
                    recover: recover.clone(),
                    parallelism: opts.parallelism,
                    element,
                    foundation,
                    ..Default::default()
                },
            );
            let setup_ms = t0.elapsed().as_secs_f64() * 1e3;
            match solver {
                Ok(solver) => solvers.push((support, solver, setup_ms)),
                Err(e) => rows.push(Row {
                    setup_ms,
                    error: Some(e.to_string()),
                    ..row(&label, element, support)
                }),
            }
        }
        let steps = if strategy == Strategy::NeoHookean {
            opts.steps.min(2)
        } else {
            opts.steps
        }
        .max(1);
        for &m in &opts.contact_counts {
            let m = m.min(surface.len());
            let total = steps + 1;
            // Every contact vertex pressed to `d` along -z.
            let pressed = |d: f64| -> Vec<Prescribed> {
                surface[..m]
                    .iter()
                    .map(|&node| Prescribed {
                        node,
                        displacement: Vector3::new(0.0, 0.0, -d),
                    })
                    .collect()
            };
            let mut out: Vec<Row> = solvers
                .iter()
                .map(|(support, _, setup_ms)| Row {
                    contact_vertices: m,
                    setup_ms: *setup_ms,
                    ..row(&label, element, *support)
                })
                .collect();
            let first = pressed(opts.depth_m / total as f64);
            for ((_, solver, _), r) in solvers.iter_mut().zip(&mut out) {
                let t1 = Instant::now();
                let result = solver.solve(&first).map(|s| s.iterations);
                r.first_step_ms = t1.elapsed().as_secs_f64() * 1e3;
                r.error = result.err().map(|e| e.to_string());
            }
            let mut spent_s = vec![0.0; out.len()];
            let mut iters = vec![0u64; out.len()];
            for k in 0..steps {
                let pres = pressed(opts.depth_m * (k + 2) as f64 / total as f64);
                for (i, ((_, solver, _), r)) in solvers.iter_mut().zip(&mut out).enumerate() {
                    if r.error.is_some() {
                        continue;
                    }
                    let t2 = Instant::now();
                    match solver.solve(&pres) {
                        Ok(sol) => {
                            iters[i] += sol.iterations as u64;
                            spent_s[i] += t2.elapsed().as_secs_f64();
                            r.steps += 1;
                        }
                        Err(e) => r.error = Some(e.to_string()),
                    }
                }
            }
            for (i, r) in out.iter_mut().enumerate() {
                if r.steps > 0 {
                    r.ms_per_step = spent_s[i] * 1e3 / r.steps as f64;
                    r.iterations = iters[i] as f64 / r.steps as f64;
                }
            }
            rows.extend(out);
        }
    }
    set_over_stem(&mut rows);
    rows
}

/// The outer triangles of `mesh` whose centroid lies farther than
/// `open_m` from `top`.
fn foundation_faces(mesh: &TetMesh, top: Point3<f64>, open_m: f64) -> Vec<[u32; 3]> {
    outer_faces_where(mesh, |c| (c - top).norm() > open_m)
}

/// Sets [`Row::over_stem`]: each row's time per step over the same
/// (strategy, element, contact count) row's on the stem alone.
fn set_over_stem(rows: &mut [Row]) {
    for i in 0..rows.len() {
        let r = &rows[i];
        if r.support == Support::Stem.label() {
            continue;
        }
        let stem = rows.iter().find(|s| {
            s.support == Support::Stem.label()
                && s.strategy == r.strategy
                && s.element == r.element
                && s.contact_vertices == r.contact_vertices
        });
        let over = stem.map(|s| r.ms_per_step / s.ms_per_step);
        rows[i].over_stem = over;
    }
}

/// Prints rows as a table, or as JSON when `json`.
pub fn print(rows: &[Row], json: bool) {
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(rows).unwrap_or_else(|e| format!("\"{e}\""))
        );
        return;
    }
    println!(
        "{:<12} {:>7} {:<20} {:<20} {:<28} {:>8} {:>11} {:>8} {:>13} {:>10} {:>6} {:>7}  error",
        "preset",
        "tets",
        "strategy",
        "element",
        "support",
        "contact",
        "ms/step",
        "/ stem",
        "first step ms",
        "setup ms",
        "iters",
        "threads"
    );
    for r in rows {
        let ratio = r.over_stem.map_or("-".to_string(), |x| format!("{x:.2}"));
        println!(
            "{:<12} {:>7} {:<20} {:<20} {:<28} {:>8} {:>11.2} {:>8} {:>13.2} {:>10.1} {:>6.1} {:>7}  {}",
            r.preset,
            r.tets,
            r.strategy,
            r.element,
            r.support,
            r.contact_vertices,
            r.ms_per_step,
            ratio,
            r.first_step_ms,
            r.setup_ms,
            r.iterations,
            r.threads,
            r.error.as_deref().unwrap_or("")
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fissure_engine::mesh::blocks::cuboid;

    #[test]
    fn small_bench_produces_rows_for_every_strategy_and_element() {
        let mesh = cuboid([0.02, 0.02, 0.01], [4, 4, 2]);
        let opts = FemBenchOptions {
            contact_counts: vec![3, 6],
            steps: 1,
            ..Default::default()
        };
        let rows = run_fem_bench(&mesh, "tiny", &opts);
        // 4 strategies and compliance-surface with tet4, all but
        // corotational again with the nodal-pressure element; 2 contact
        // counts.
        assert_eq!(rows.len(), (5 + 4) * 2);
        assert_eq!(
            rows.iter()
                .filter(|r| r.element == "tet4-nodal-pressure")
                .count(),
            4 * 2
        );
        assert!(
            rows.iter()
                .any(|r| r.element == "tet4-nodal-pressure" && r.strategy == "neo-hookean")
        );
        for r in &rows {
            assert!(r.error.is_none(), "{r:?}");
            assert!(r.ms_per_step.is_finite() && r.ms_per_step >= 0.0);
        }
    }
    /// With a foundation beside the stem, each row runs on both supports at
    /// the same contact set and carries its ratio to the stem's, the
    /// nonlinear strategies' too.
    #[test]
    fn a_foundation_runs_beside_the_stem_on_the_same_contact_set() {
        let mesh = cuboid([0.06, 0.06, 0.03], [6, 6, 3]);
        let opts = FemBenchOptions {
            strategies: vec![Strategy::Compliance, Strategy::Corotational],
            elements: vec![Element::Tet4],
            compliance_surface_too: false,
            contact_counts: vec![4],
            steps: 1,
            supports: vec![
                Support::Stem,
                Support::Foundation {
                    stiffness_pa_per_m: 1e8,
                },
            ],
            ..Default::default()
        };
        // The opening leaves the top's middle free and supports the rest.
        let (lo, hi) = mesh.bounds();
        let top = Point3::new(0.5 * (lo.x + hi.x), 0.5 * (lo.y + hi.y), hi.z);
        let faces = foundation_faces(&mesh, top, FOUNDATION_OPEN_M);
        let all = mesh.boundary().triangles.len();
        assert!(
            !faces.is_empty() && faces.len() < all,
            "{} of {all}",
            faces.len()
        );
        let rows = run_fem_bench(&mesh, "box", &opts);
        let labels: Vec<(&str, &str)> = rows
            .iter()
            .map(|r| (r.strategy.as_str(), r.support.as_str()))
            .collect();
        assert_eq!(
            labels,
            [
                ("compliance", "stem"),
                ("compliance", "foundation 1.000e8 Pa/m"),
                ("corotational", "stem"),
                ("corotational", "foundation 1.000e8 Pa/m"),
            ]
        );
        for r in &rows {
            assert!(r.error.is_none(), "{r:?}");
        }
        assert_eq!(rows[0].over_stem, None);
        let over = rows[1].over_stem.expect("the foundation's row has a ratio");
        assert_eq!(over, rows[1].ms_per_step / rows[0].ms_per_step);
        assert!(rows[3].over_stem.is_some(), "{:?}", rows[3]);
    }
}
