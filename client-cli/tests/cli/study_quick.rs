//! `fissure study --quick`: the whole pipeline on the coarse phantom, with the
//! stability results asserted.

use fissure_cli::lab::study::plan::{PlanOptions, Role, StudyPlan};
use fissure_cli::lab::study::runs::{Outcome, run_range};
use fissure_cli::lab::study::{StudyArgs, StudyError, merge, record, run_study};
use std::path::Path;

/// The measured times (the machine's, never equal between two runs).
const TIMING: [&str; 6] = [
    "ms_per_step",
    "collision_ms",
    "us_per_sample",
    "us_per_sample_p99",
    "setup_ms",
    "total_s",
];

/// `study.json` of `dir` without the measured times.
fn values(dir: &Path) -> serde_json::Value {
    fn strip(v: &mut serde_json::Value) {
        match v {
            serde_json::Value::Object(m) => {
                m.retain(|k, _| !TIMING.contains(&k.as_str()));
                m.values_mut().for_each(strip);
            }
            serde_json::Value::Array(a) => a.iter_mut().for_each(strip),
            _ => {}
        }
    }
    let text = std::fs::read_to_string(dir.join("study.json")).expect("study.json");
    let mut v: serde_json::Value = serde_json::from_str(&text).expect("study.json parses");
    strip(&mut v);
    v
}

fn read(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn quick_study_is_stable_and_consistent() {
    let dir = tempfile::tempdir().expect("temporary folder");
    let args = StudyArgs {
        out: dir.path().to_path_buf(),
        options: PlanOptions {
            quick: true,
            ..PlanOptions::default()
        },
        resume: false,
        json: false,
        no_progress: true,
    };
    let res = run_study(&args).expect("the quick study runs");

    // Every check of the stability sweep holds (finite everywhere, force
    // linear in E within 1%, nu = 0.499 locks the linear tetrahedra by at
    // least 1.5x, the nodal-pressure element's F(0.4999) / F(0.45) within
    // 10% of its reference on paper-48k, the nominal run has no inverted
    // element).
    for c in &res.checks {
        assert!(c.passed, "check failed: {} ({})", c.name, c.detail);
    }
    assert!(res.checks.len() >= 5, "checks: {:?}", res.checks);
    assert!(
        res.checks
            .iter()
            .any(|c| c.name.contains("tet4-nodal-pressure") && c.name.contains("paper-48k")),
        "no nodal-pressure check: {:?}",
        res.checks
    );
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
        // A force sample equals a full solve at its poses: where a sample
        // falls on a step's instant, the step (the full solve at that
        // sample's poses and history) gives the sample's force to the
        // contact solver's tolerance, though the sample's model is a whole
        // interval old.
        let h = r.haptic.expect("samples fall on the steps' instants");
        assert!(
            h.checked >= 10 && h.max_pct < 1e-3,
            "{}: {h:?}",
            r.config.label
        );
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

    // The study is its folder: merging its result files again writes the
    // same bytes (a merge is a function of the result files).
    let again = tempfile::tempdir().expect("temporary folder");
    merge::merge(dir.path(), again.path(), false).expect("the merge of a complete study");
    for f in ["grid.csv", "stability.csv", "study.json"] {
        assert!(
            read(&dir.path().join(f)) == read(&again.path().join(f)),
            "{f} differs between the study and a merge of its runs"
        );
    }

    // A run whose result is gone: the merge refuses, naming it; with
    // --allow-missing it writes the rest and names it in the outputs.
    let plan = StudyPlan::read(dir.path()).expect("the study wrote its plan");
    let (lost, lost_run) = plan
        .runs
        .iter()
        .enumerate()
        .rfind(|(_, r)| r.role == Role::Stability)
        .expect("a stability run");
    std::fs::remove_file(record::result_path(dir.path(), &lost_run.id)).expect("result file");
    match merge::merge(dir.path(), again.path(), false) {
        Err(e @ StudyError::Incomplete { .. }) => {
            let text = e.to_string();
            assert!(
                text.contains(&format!("{} (index {lost}, missing)", lost_run.id))
                    && text.contains(&format!("--array={lost}")),
                "{text}"
            );
        }
        other => panic!("a merge with a run missing: {other:?}"),
    }
    let partial = merge::merge(dir.path(), again.path(), true).expect("--allow-missing merges");
    assert_eq!(partial.absent.len(), 1);
    assert_eq!(partial.stability.len(), res.stability.len() - 1);
    let md = std::fs::read_to_string(again.path().join("study.md")).expect("study.md");
    assert!(
        md.contains(&lost_run.id) && md.contains("Incomplete"),
        "{md}"
    );

    // Running the study folder again computes only the missing run, and the
    // study's values come back unchanged.
    let outcomes = run_range(dir.path(), &plan, 0..plan.runs.len(), false, true).expect("runs");
    for (i, o) in &outcomes {
        if *i == lost {
            assert!(matches!(o, Outcome::Computed { .. }), "{i}: {o:?}");
        } else {
            assert_eq!(*o, Outcome::Skipped, "run {i} was computed again");
        }
    }
    let before = values(dir.path());
    merge::merge(dir.path(), again.path(), false).expect("complete again");
    assert!(
        values(again.path()) == before,
        "the recomputed run changed the study's values"
    );

    // A run that cannot be set up writes a failure record naming the cause,
    // and the merge names it failed.
    let mut broken = plan.clone();
    broken.runs[lost].config.preset = "no-such-preset".into();
    let path = StudyPlan::path(dir.path());
    std::fs::write(&path, serde_json::to_string_pretty(&broken).expect("json")).expect("plan");
    std::fs::remove_file(record::result_path(dir.path(), &lost_run.id)).expect("result file");
    let outcomes = run_range(dir.path(), &broken, lost..lost + 1, false, true).expect("runs");
    let Outcome::Failed(cause) = &outcomes[0].1 else {
        panic!("a run of an unknown preset: {:?}", outcomes[0]);
    };
    assert!(cause.contains("no-such-preset"), "{cause}");
    let e = merge::merge(dir.path(), again.path(), false).expect_err("a failed run");
    assert!(
        e.to_string()
            .contains(&format!("{} (index {lost}, failed: ", lost_run.id)),
        "{e}"
    );

    // Runs read the shared inputs from the folder: without its trajectory a
    // run fails naming the file.
    std::fs::remove_file(dir.path().join(&plan.inputs.left)).expect("the left trajectory");
    let outcomes = run_range(dir.path(), &plan, lost..lost + 1, true, true).expect("runs");
    let Outcome::Failed(cause) = &outcomes[0].1 else {
        panic!("a run without its inputs: {:?}", outcomes[0]);
    };
    assert!(cause.contains("sylvian-open-left.csv"), "{cause}");

    // A folder holding only the plan (copied without its inputs or runs
    // folder) records each run's failure, making the runs folder.
    let bare = tempfile::tempdir().expect("temp dir");
    std::fs::copy(dir.path().join("plan.json"), bare.path().join("plan.json"))
        .expect("copy the plan");
    let outcomes = run_range(bare.path(), &plan, 0..1, false, true).expect("runs");
    let Outcome::Failed(cause) = &outcomes[0].1 else {
        panic!("a run of a folder without inputs: {:?}", outcomes[0]);
    };
    assert!(cause.contains("inputs"), "{cause}");
    let record = record::FailureRecord::read(bare.path(), &plan.runs[0].id)
        .expect("readable")
        .expect("the failure is recorded");
    assert_eq!(&record.cause, cause);
}
