//! The study through a real single-node Slurm (`client-cli/slurm/ci-test.sh`):
//! the quick study submitted as a job array of `client-cli/slurm/study.sbatch`
//! and merged equals the one-process study in every value but the measured
//! times, and a task cancelled midway is named missing by the merge and
//! completed by resubmitting it alone.
//!
//! Needs Debian's `slurm-wlm` and `munge` (`.ci/run` installs them). Without
//! them the test says so and passes, except under CI (`CI` set), where a
//! missing Slurm is a failure: CI must run it.

use std::path::Path;
use std::process::Command;

fn have(tool: &str) -> bool {
    Command::new("sh")
        .args(["-c", &format!("command -v {tool}")])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false)
}

#[test]
fn a_slurm_job_array_gives_the_one_process_study_and_a_cancelled_task_resubmits_alone() {
    let missing: Vec<&str> = [
        "sbatch",
        "squeue",
        "scancel",
        "slurmctld",
        "slurmd",
        "munged",
        "mungekey",
    ]
    .into_iter()
    .filter(|t| !have(t))
    .collect();
    if !missing.is_empty() {
        let ci = std::env::var("CI").is_ok_and(|v| !v.is_empty() && v != "false" && v != "0");
        assert!(
            !ci,
            "CI must run the Slurm test, but {} not found (install slurm-wlm and munge)",
            missing.join(", ")
        );
        eprintln!(
            "skipping the Slurm study test: {} not found (install Debian's slurm-wlm and munge to run it)",
            missing.join(", ")
        );
        return;
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let work = tempfile::tempdir().expect("temporary folder");
    let out = Command::new(root.join("client-cli/slurm/ci-test.sh"))
        .arg(env!("CARGO_BIN_EXE_fissure"))
        .arg(work.path())
        .output()
        .expect("client-cli/slurm/ci-test.sh runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "client-cli/slurm/ci-test.sh failed ({}):\n{stdout}\n{stderr}",
        out.status
    );
    // What it measured, for the log (`cargo test -- --nocapture`).
    println!("{stdout}");
    assert!(stdout.contains("ci-test: passed"), "{stdout}");
    assert!(
        stdout.contains("equal but for the measured times"),
        "no comparison was made: {stdout}"
    );
}
