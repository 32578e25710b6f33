//! One deformation step per strategy on a 48k-tet cuboid (80 x 80 x 50 mm,
//! 20 x 20 x 20 blocks), timed by [`fissure_cli::lab::bench::fem`]: prints its
//! table and its Markdown form. Run with
//! `cargo bench -p fissure-cli --bench fem_cuboid`.

use fissure_cli::lab::bench::fem::{FemBenchOptions, print, run_fem_bench};
use fissure_engine::mesh::blocks::cuboid;

fn main() {
    let mesh = cuboid([0.08, 0.08, 0.05], [20, 20, 20]);
    let rows = run_fem_bench(&mesh, "cuboid-48k", &FemBenchOptions::default());
    print(&rows, false);
    print(&rows, true);
}
