//! `fissure study --quick`: the whole pipeline on the coarse phantom, with the
//! stability results asserted.

use fissure_cli::study::{StudyArgs, run_study};

#[test]
fn quick_study_is_stable_and_consistent() {
    let dir = tempfile::tempdir().expect("temporary folder");
    let args = StudyArgs {
        out: dir.path().to_path_buf(),
        quick: true,
        json: false,
        rate_hz: None,
        window_s: None,
        no_grid: false,
        no_stability: false,
        no_progress: true,
    };
    let res = run_study(&args).expect("the quick study runs");

    // Every check of the stability sweep holds (finite everywhere, force
    // linear in E within 1%, nu = 0.499 locks the linear tetrahedra by at
    // least 1.5x, the nominal run has no inverted element).
    for c in &res.checks {
        assert!(c.passed, "check failed: {} ({})", c.name, c.detail);
    }
    assert!(res.checks.len() >= 4, "checks: {:?}", res.checks);
    for s in &res.stability {
        assert!(s.row.finite, "{} not finite", s.row.config.label);
        assert!(s.row.steps > 0, "{} took no step", s.row.config.label);
    }
    // The spatulas load the tissue in the nominal run.
    let nominal = res
        .stability
        .iter()
        .find(|s| s.dimension == "nominal")
        .expect("a nominal run");
    assert!(
        nominal.row.final_force_n[0] > 1e-4 && nominal.row.final_force_n[1] > 1e-4,
        "final forces {:?} N",
        nominal.row.final_force_n
    );
    // Slowing the spatula down 1.6x leaves the quasi-static end state alone.
    let slow = res
        .stability
        .iter()
        .find(|s| s.dimension == "speed" && s.row.speed_mps < 0.015)
        .expect("a 10 mm/s run");
    let e = slow.force_error_pct.expect("speed runs have a force error");
    assert!(e.abs() < 5.0, "10 mm/s: force error {e}%");

    // `compliance` is exact linear elasticity: it matches the `direct`
    // reference to rounding, whatever the ray backend. The paper's rule is
    // another contact law: it differs from the frictionless reference.
    for r in &res.grid {
        let e = r.errors.expect("grid rows have errors");
        if r.config.sweep == "contact" {
            assert!(
                e.rms_mm > 1e-3 && e.rms_mm.is_finite(),
                "{}: the paper's rule equals frictionless contact: {e:?}",
                r.config.label
            );
            continue;
        }
        assert!(
            e.points > 10,
            "{}: {} region points",
            r.config.label,
            e.points
        );
        assert!(
            e.rms_mm < 1e-6 && e.force_rms_pct[0] < 1e-4 && e.force_rms_pct[1] < 1e-4,
            "{}: {e:?}",
            r.config.label
        );
        assert!(r.ms_per_step > 0.0 && r.us_per_sample > 0.0);
    }

    for f in [
        "grid.csv",
        "stability.csv",
        "study.md",
        "study.json",
        "error-vs-step-time.png",
        "forces-all.png",
    ] {
        let p = dir.path().join(f);
        let len = std::fs::metadata(&p).map(|m| m.len()).unwrap_or(0);
        assert!(len > 100, "{} missing or empty", p.display());
    }
}
