#!/usr/bin/env bash
# Runs every fuzz target (or the ones named) for a bounded time each.
#
#   server/fuzz/run.sh SECONDS [TARGET...]
#
# Needs a nightly toolchain and cargo-fuzz (`cargo install cargo-fuzz`).
# Each target starts from its seeds (seeds/<target>, written by make_seeds.py)
# and keeps what it learns in corpus/<target> (not tracked). Limits: 2 GiB
# resident memory for the whole process, 256 MiB for any single allocation,
# 10 s for any single input. A crash, a limit hit or a hang writes the input
# to artifacts/<target>/ and makes this script fail. A summary line per target
# (executions, seconds, corpus size, peak RSS) goes to stdout and logs/summary.
set -euo pipefail

secs="${1:?usage: run.sh SECONDS [TARGET...]}"
shift
cd "$(dirname "$0")"
if [ "$#" -gt 0 ]; then
    targets=("$@")
else
    targets=(msh vtk vtu tetgen obj ply stl scene pose bridge igtl nifti)
fi
toolchain="${FUZZ_TOOLCHAIN:-nightly}"
sanitizer="${FUZZ_SANITIZER:-address}"

for t in "${targets[@]}"; do
    cargo "+$toolchain" fuzz build --sanitizer "$sanitizer" "$t"
done

mkdir -p logs
: > logs/summary
status=0
for t in "${targets[@]}"; do
    mkdir -p "corpus/$t" "artifacts/$t"
    if ! cargo "+$toolchain" fuzz run --sanitizer "$sanitizer" "$t" "corpus/$t" "seeds/$t" -- \
        -max_total_time="$secs" -rss_limit_mb=2048 -malloc_limit_mb=256 -timeout=10 \
        -print_final_stats=1 -artifact_prefix="artifacts/$t/" > "logs/$t.log" 2>&1; then
        status=1
        echo "$t: FAILED (see server/fuzz/logs/$t.log and artifacts/$t/)" | tee -a logs/summary
        continue
    fi
    execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "logs/$t.log" | tail -1)
    rss=$(sed -n 's/^stat::peak_rss_mb: *//p' "logs/$t.log" | tail -1)
    corpus=$(find "corpus/$t" -type f | wc -l)
    echo "$t: ${execs:-?} executions in ${secs} s, corpus ${corpus} inputs, peak RSS ${rss:-?} MB, no crash" \
        | tee -a logs/summary
done
exit "$status"
