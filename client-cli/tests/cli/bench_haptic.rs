//! `fissure bench haptic` on the cube's press/hold/retract: what the force
//! loop must give whatever the machine's speed, and the README's table of
//! the command's flags.

use fissure_cli::client::trajectory::Trajectory;
use fissure_cli::lab::bench::haptic::{SummaryOptions, measure, plan, summarise};
use fissure_engine::scene::Scene;
use fissure_engine::sim::core::engine::Model;
use std::sync::Arc;

/// The left plate pressed 3 mm into the cube, held and lifted, every
/// sample against a full solve at that sample's pose. Linear elasticity
/// with frictionless contact: the force loop solves the full solve's
/// contact problem on the same compliance, so each sample equals it (to
/// 1% of the peak force); every force is finite; the tissue only pushes
/// the plate (F . (-n) >= 0 on the pressing face), and it does so exactly
/// while the plate is below the block's rest top surface.
#[test]
fn cube_press_hold_retract_samples_equal_a_full_solve_and_only_push() {
    let runs = plan(&["cube".into()], &["cube-press-hold-retract-left".into()]).unwrap();
    assert_eq!(runs.len(), 1);
    let (scene, _) = Scene::load("cube").unwrap();
    let model = Arc::new(Model::build(&scene).unwrap());
    let left = scene
        .instruments
        .iter()
        .position(|s| s.name == "left")
        .unwrap();
    let traj = Trajectory::load("cube-press-hold-retract-left").unwrap();
    let m = measure(&scene, &model, &[(left, traj)], None, &mut |_, _| {}).unwrap();
    let s = &m.series[0];
    assert_eq!(s.t_s.len(), 2001);
    for (k, f) in s.sample_n.iter().enumerate() {
        assert!(f.iter().all(|c| c.is_finite()), "t = {} s: {f:?}", s.t_s[k]);
    }
    let measured: Vec<(f64, f64)> = s
        .t_s
        .iter()
        .zip(&s.normal_n)
        .filter_map(|(t, n)| n.map(|n| (*t, n)))
        .collect();
    // The plate is in contact for about a second of the two.
    assert!(
        measured.len() > 500,
        "{} samples in contact",
        measured.len()
    );
    for (t, n) in &measured {
        assert!(
            *n >= -1e-9,
            "t = {t} s: the tissue pulls the plate, F.n = {n} N"
        );
    }
    // The block pushes back at every depth below its rest top surface and
    // not above it, on the way in and on the way out.
    for k in 0..s.t_s.len() {
        let (d, f) = (s.depth_m[k], s.sample_n[k].norm());
        assert!(
            (d > 1e-9 && f > 0.0) || (d < -1e-9 && f == 0.0) || d.abs() <= 1e-9,
            "t = {} s: depth {d:.3e} m, |F| = {f:.3e} N",
            s.t_s[k]
        );
    }
    let row = summarise(
        &m,
        &runs[0]
            .tracks
            .iter()
            .map(|t| t.1.clone())
            .collect::<Vec<_>>(),
        &SummaryOptions::default(),
    );
    assert!(row.peak_force_n > 0.1, "{row:?}");
    let e = row.max_error_rel.unwrap();
    assert!(
        e <= 1e-2,
        "max |F_sample - F_full| = {:.3e} N ({:.3}% of the peak {:.4} N) at t = {:?} s: sample {:?}, full {:?}",
        row.max_error_n,
        e * 100.0,
        row.peak_force_n,
        row.max_error_at_s,
        row.max_error_sample_n,
        row.max_error_full_n
    );
}

/// README.md gives every flag of `fissure bench haptic --help` in its table
/// for the command, with the default `--help` shows.
#[test]
fn the_readme_gives_every_bench_haptic_flag_with_its_default() {
    let help = std::process::Command::new(env!("CARGO_BIN_EXE_fissure"))
        .args(["bench", "haptic", "--help"])
        .output()
        .expect("fissure bench haptic --help");
    let help = String::from_utf8_lossy(&help.stdout).into_owned();
    let readme = include_str!("../../../README.md");
    let table: Vec<&str> = readme
        .lines()
        .skip_while(|l| !l.starts_with("| `fissure bench haptic` flag"))
        .take_while(|l| l.starts_with('|'))
        .collect();
    assert!(
        table.len() > 2,
        "README has no `fissure bench haptic` flag table"
    );
    let mut flags: Vec<(String, Option<String>)> = Vec::new();
    for line in help.lines() {
        if let Some(rest) = line.strip_prefix("      --") {
            flags.push((rest.split([' ', '=']).next().unwrap_or("").to_owned(), None));
        }
        if let (Some(last), Some(d)) = (flags.last_mut(), line.split("[default: ").nth(1)) {
            last.1 = Some(d.trim_end_matches(']').to_owned());
        }
    }
    let flags: Vec<_> = flags
        .into_iter()
        .filter(|(n, _)| n != "help" && n != "version")
        .collect();
    assert!(flags.len() >= 7, "{flags:?}");
    for (name, default) in flags {
        let row = table
            .iter()
            .find(|r| r.contains(&format!("`--{name}")))
            .unwrap_or_else(|| panic!("README's bench haptic table has no row for --{name}"));
        if let Some(d) = default {
            assert!(
                row.contains(&format!("`{d}`")),
                "--{name}: default {d} not in {row}"
            );
        }
    }
}
