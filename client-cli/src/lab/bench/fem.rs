//! Deformation-step benchmark: time per step of each FEM strategy on a mesh
//! with a growing contact set (surface vertices nearest the top centre,
//! indented along -z), bottom nodes fixed.
//!
//! Each (strategy, contact count) runs one untimed warm-up step (it caches
//! the compliance columns of the new contact nodes) and then `steps` timed
//! steps at increasing indentation depth; `ms_per_step` is their mean.
//! The linear strategies run with each element formulation asked for
//! (`tet4`, `tet4-nodal-pressure`), side by side in one run.

use fissure_engine::fem::compliance::Recover;
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
    /// Element formulations (the nonlinear strategies take `tet4` only).
    pub elements: Vec<Element>,
}

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
    /// Contact vertices.
    pub contact_vertices: usize,
    /// Mean time per timed step, ms.
    pub ms_per_step: f64,
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
    let mut variants: Vec<(Strategy, Element, Recover, String)> = Vec::new();
    for &s in &opts.strategies {
        for &e in &opts.elements {
            if e != Element::Tet4 && !s.is_linear() {
                continue;
            }
            variants.push((s, e, Recover::All, s.name().to_string()));
            if s == Strategy::Compliance && opts.compliance_surface_too {
                variants.push((s, e, Recover::Surface, "compliance-surface".into()));
            }
        }
    }
    let mut rows = Vec::new();
    for (strategy, element, recover, label) in variants {
        let t0 = Instant::now();
        let solver = build_solver(
            strategy,
            mesh,
            opts.material,
            &fixed,
            &SolverOptions {
                recover,
                parallelism: opts.parallelism,
                element,
                ..Default::default()
            },
        );
        let setup_ms = t0.elapsed().as_secs_f64() * 1e3;
        let mut solver = match solver {
            Ok(s) => s,
            Err(e) => {
                rows.push(Row {
                    preset: preset_name.into(),
                    tets: mesh.tets.len(),
                    nodes: mesh.nodes.len(),
                    strategy: label.clone(),
                    element: element.name().into(),
                    contact_vertices: 0,
                    ms_per_step: f64::NAN,
                    first_step_ms: f64::NAN,
                    setup_ms,
                    iterations: 0.0,
                    steps: 0,
                    threads: opts.parallelism.degree(),
                    error: Some(e.to_string()),
                });
                continue;
            }
        };
        let steps = if strategy == Strategy::NeoHookean {
            opts.steps.min(2)
        } else {
            opts.steps
        }
        .max(1);
        for &m in &opts.contact_counts {
            let m = m.min(surface.len());
            let contact = &surface[..m];
            let mut pres: Vec<Prescribed> = contact
                .iter()
                .map(|&node| Prescribed {
                    node,
                    displacement: Vector3::zeros(),
                })
                .collect();
            let set_depth = |pres: &mut Vec<Prescribed>, d: f64| {
                for p in pres.iter_mut() {
                    p.displacement = Vector3::new(0.0, 0.0, -d);
                }
            };
            let total = steps + 1;
            set_depth(&mut pres, opts.depth_m / total as f64);
            let t1 = Instant::now();
            let first = solver.solve(&pres).map(|s| s.iterations);
            let first_step_ms = t1.elapsed().as_secs_f64() * 1e3;
            let mut error = first.err().map(|e| e.to_string());
            let mut iters = 0u64;
            let t2 = Instant::now();
            let mut done = 0;
            if error.is_none() {
                for k in 0..steps {
                    set_depth(&mut pres, opts.depth_m * (k + 2) as f64 / total as f64);
                    match solver.solve(&pres) {
                        Ok(s) => iters += s.iterations as u64,
                        Err(e) => {
                            error = Some(e.to_string());
                            break;
                        }
                    }
                    done += 1;
                }
            }
            let ms = t2.elapsed().as_secs_f64() * 1e3 / done.max(1) as f64;
            rows.push(Row {
                preset: preset_name.into(),
                tets: mesh.tets.len(),
                nodes: mesh.nodes.len(),
                strategy: label.clone(),
                element: element.name().into(),
                contact_vertices: m,
                ms_per_step: if done > 0 { ms } else { f64::NAN },
                first_step_ms,
                setup_ms,
                iterations: iters as f64 / done.max(1) as f64,
                steps: done,
                threads: opts.parallelism.degree(),
                error,
            });
        }
    }
    rows
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
        "{:<12} {:>7} {:<20} {:<20} {:>8} {:>11} {:>13} {:>10} {:>6} {:>7}  error",
        "preset",
        "tets",
        "strategy",
        "element",
        "contact",
        "ms/step",
        "first step ms",
        "setup ms",
        "iters",
        "threads"
    );
    for r in rows {
        println!(
            "{:<12} {:>7} {:<20} {:<20} {:>8} {:>11.2} {:>13.2} {:>10.1} {:>6.1} {:>7}  {}",
            r.preset,
            r.tets,
            r.strategy,
            r.element,
            r.contact_vertices,
            r.ms_per_step,
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
        // 4 strategies and compliance-surface with tet4, the 3 linear
        // variants again with the nodal-pressure element; 2 contact counts.
        assert_eq!(rows.len(), (5 + 3) * 2);
        assert_eq!(
            rows.iter()
                .filter(|r| r.element == "tet4-nodal-pressure")
                .count(),
            3 * 2
        );
        for r in &rows {
            assert!(r.error.is_none(), "{r:?}");
            assert!(r.ms_per_step.is_finite() && r.ms_per_step >= 0.0);
        }
    }
}
