#!/usr/bin/env bash
# The study's Slurm path against a real single-node Slurm (munged,
# slurmctld, slurmd on this machine; client-cli/slurm/local-cluster.sh):
#
# 1. `fissure study --quick` in one process, timed;
# 2. the same study planned, submitted as a job array of
#    client-cli/slurm/study.sbatch, waited for (bounded), merged, timed: its
#    grid.csv, stability.csv and study.json must equal the single process's
#    in every value but the measured times (compare_outputs.py);
# 3. a grid-only study whose task 1 is cancelled (scancel) while it runs:
#    the merge must fail naming that run missing; resubmitting only task 1
#    completes it, and the merged grid equals the single process's.
#
# usage: client-cli/slurm/ci-test.sh FISSURE_BINARY WORK_DIR
# Prints the wall times and their ratio, and writes them to
# WORK_DIR/timings.json. Stops the daemons it started, whatever happens.
set -euo pipefail

if [ $# -ne 2 ]; then
    echo "usage: $0 FISSURE_BINARY WORK_DIR" >&2
    exit 2
fi
here="$(cd "$(dirname "$0")" && pwd)"
FISSURE="$(cd "$(dirname "$1")" && pwd)/$(basename "$1")"
export FISSURE
mkdir -p "$2"
work="$(cd "$2" && pwd)"
cluster="$work/cluster"
# Bounded waits, s.
ARRAY_TIMEOUT_S="${ARRAY_TIMEOUT_S:-1800}"

"$here/local-cluster.sh" start "$cluster"
trap '"$here/local-cluster.sh" stop "$cluster"' EXIT
export SLURM_CONF="$cluster/slurm.conf"

now() { date +%s.%N; }

# Waits until job $1 has left the queue; fails after $2 s.
wait_job() {
    local job="$1" limit="$2" start
    start="$(date +%s)"
    while [ -n "$(squeue -h -j "$job" -o %i 2>/dev/null)" ]; do
        if [ $(( $(date +%s) - start )) -gt "$limit" ]; then
            echo "ci-test: job $job still queued after $limit s:" >&2
            squeue -j "$job" >&2 || true
            scancel "$job" || true
            return 1
        fi
        sleep 0.2
    done
}

# Waits until task $2 of array job $1 runs; fails after $3 s.
wait_running() {
    local job="$1" task="$2" limit="$3" start
    start="$(date +%s)"
    until [ "$(squeue -h -j "${job}_${task}" -o %T 2>/dev/null)" = "RUNNING" ]; do
        if [ $(( $(date +%s) - start )) -gt "$limit" ]; then
            echo "ci-test: task ${job}_${task} did not start in $limit s" >&2
            return 1
        fi
        sleep 0.1
    done
}

runs_of() { python3 -c 'import json,sys; print(len(json.load(open(sys.argv[1]))["runs"]))' "$1/plan.json"; }

echo "== 1. the quick study in one process"
t0="$(now)"
"$FISSURE" study --quick --out "$work/single" --no-progress >"$work/single.log" 2>&1 || { cat "$work/single.log" >&2; exit 1; }
t_single="$(python3 -c "print($(now) - $t0)")"
echo "one process: ${t_single} s"

# Plans the quick study into $1, submits it as an array (one run a task, or
# $2 blocks), waits, merges, and prints the wall time of the whole.
slurm_study() {
    local dir="$1" blocks="${2:-}" n t0 job
    t0="$(now)"
    "$FISSURE" study plan --quick --out "$dir" >/dev/null
    n="$(runs_of "$dir")"
    mkdir -p "$dir/logs"
    if [ -n "$blocks" ]; then
        job="$(sbatch --parsable --array=0-$((blocks - 1)) --output="$dir/logs/%A_%a.out" \
            "$here/study.sbatch" "$dir" "$blocks")"
    else
        job="$(sbatch --parsable --array=0-$((n - 1)) --output="$dir/logs/%A_%a.out" \
            "$here/study.sbatch" "$dir")"
    fi
    wait_job "$job" "$ARRAY_TIMEOUT_S"
    "$FISSURE" study merge "$dir" >"$dir/merge.log" 2>&1 || {
        echo "ci-test: the merge of the Slurm study in $dir failed:" >&2
        cat "$dir/merge.log" "$dir"/logs/*.out >&2
        return 1
    }
    python3 -c "print(round($(now) - $t0, 3))"
}

echo "== 2. the quick study as a Slurm job array, one run a task"
t_slurm="$(slurm_study "$work/slurm")"
echo "Slurm job array of $(runs_of "$work/slurm") tasks: ${t_slurm} s"
python3 "$here/compare_outputs.py" "$work/single" "$work/slurm"

echo "== 2b. the same as an array of 2 blocks of runs (--shard I/2)"
t_blocks="$(slurm_study "$work/blocks" 2)"
echo "Slurm job array of 2 blocks: ${t_blocks} s"
python3 "$here/compare_outputs.py" "$work/single" "$work/blocks"

echo "== 3. a task cancelled midway, then resubmitted alone"
# Force samples at 500 Hz make run 2 (the brute-force ray backend) last
# seconds, long enough to be cancelled while it runs.
"$FISSURE" study plan --quick --no-stability --rate-hz 500 --out "$work/cancel" >/dev/null
n="$(runs_of "$work/cancel")"
mkdir -p "$work/cancel/logs"
job="$(sbatch --parsable --array=0-$((n - 1)) --output="$work/cancel/logs/%A_%a.out" \
    "$here/study.sbatch" "$work/cancel")"
wait_running "$job" 2 "$ARRAY_TIMEOUT_S"
sleep 1
scancel "${job}_2"
wait_job "$job" "$ARRAY_TIMEOUT_S"
cancelled_id="$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["runs"][2]["id"])' "$work/cancel/plan.json")"
if [ -e "$work/cancel/runs/$cancelled_id.cbor" ]; then
    echo "ci-test: task 2 ended before it was cancelled (its result is there); the test needs a longer run" >&2
    exit 1
fi
if "$FISSURE" study merge "$work/cancel" >"$work/cancel-merge.log" 2>&1; then
    echo "ci-test: the merge accepted a study whose task 2 was cancelled" >&2
    exit 1
fi
grep -q "$cancelled_id (index 2, missing)" "$work/cancel-merge.log" || {
    echo "ci-test: the merge did not name the cancelled run $cancelled_id missing:" >&2
    cat "$work/cancel-merge.log" >&2
    exit 1
}
echo "the merge names the cancelled run: $(grep -o "$cancelled_id (index 2, missing)" "$work/cancel-merge.log")"
others_before="$(cd "$work/cancel/runs" && sha256sum ./*.cbor)"
job="$(sbatch --parsable --array=2 --output="$work/cancel/logs/%A_%a.out" \
    "$here/study.sbatch" "$work/cancel")"
wait_job "$job" "$ARRAY_TIMEOUT_S"
others_after="$(cd "$work/cancel/runs" && sha256sum ./*.cbor | grep -v "$cancelled_id")"
[ "$others_before" = "$others_after" ] || {
    echo "ci-test: resubmitting task 2 changed the other runs' result files" >&2
    exit 1
}
"$FISSURE" study merge "$work/cancel" >"$work/cancel-merge.log" 2>&1 || {
    echo "ci-test: the merge after resubmitting task 2 failed:" >&2
    cat "$work/cancel-merge.log" "$work"/cancel/logs/*.out >&2
    exit 1
}
# The same plan computed in one process.
mkdir -p "$work/cancel-one"
cp -r "$work/cancel/plan.json" "$work/cancel/inputs" "$work/cancel-one/"
"$FISSURE" study run "$work/cancel-one" --no-progress >/dev/null
"$FISSURE" study merge "$work/cancel-one" >/dev/null
python3 "$here/compare_outputs.py" --files grid.csv,study.json "$work/cancel-one" "$work/cancel"

ratio="$(python3 -c "print(round($t_slurm / $t_single, 3))")"
ratio_blocks="$(python3 -c "print(round($t_blocks / $t_single, 3))")"
printf '{"single_process_s": %s, "slurm_one_run_a_task_s": %s, "slurm_2_blocks_s": %s, "ratio_one_run_a_task": %s, "ratio_2_blocks": %s}\n' \
    "$t_single" "$t_slurm" "$t_blocks" "$ratio" "$ratio_blocks" >"$work/timings.json"
echo "ci-test: passed; the quick study took ${t_single} s in one process, ${t_slurm} s through Slurm one run a task (${ratio}x) and ${t_blocks} s in 2 blocks (${ratio_blocks}x)"
