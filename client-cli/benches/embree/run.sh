#!/usr/bin/env bash
# fissure's CPU BVH against Embree 3 on the same rays, one thread each,
# interleaved runs: the comparison of docs/collision-bench.md.
#
#   client-cli/benches/embree/run.sh [ROUNDS]        (default 3 rounds)
#
# Environment:
#   FISSURE     the fissure binary (default: target/release/fissure, built
#               with `cargo build --release -p fissure-cli` when missing)
#   PRESET      phantom preset (default paper-48k)
#   NODES       source nodes per face, comma-separated (default 150,500)
#   MIN_TIME_MS least time per row, ms (default 500)
#   CORE        the one CPU both run on (default 0; empty: no pinning)
#
# Needs Embree 3 (Debian: apt-get install libembree-dev), g++, make and
# python3. Writes the ray files and the raw JSON into a temporary directory
# (kept; its path is printed) and prints a Markdown table of medians over the
# rounds: ns per line (one line = Embree's two half-rays), refit ms.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/../../.." && pwd)"
rounds="${1:-3}"
preset="${PRESET:-paper-48k}"
nodes="${NODES:-150,500}"
min_time="${MIN_TIME_MS:-500}"
core="${CORE-0}"
fissure="${FISSURE:-$root/target/release/fissure}"

if ! [[ "$rounds" =~ ^[1-9][0-9]*$ ]]; then
  echo "run.sh: ROUNDS must be a positive integer, got '$rounds'" >&2
  exit 2
fi
if ! [ -f /usr/include/embree3/rtcore.h ]; then
  echo "run.sh: Embree 3 headers not found (apt-get install libembree-dev)" >&2
  exit 2
fi
if ! [ -x "$fissure" ]; then
  echo "building fissure (release) ..." >&2
  (cd "$root" && cargo build --release -p fissure-cli --locked)
fi

work="$(mktemp -d -t fissure-embree-XXXXXX)"
make -s -C "$here" BUILD_DIR="$work" >&2
pin=()
if [ -n "$core" ] && command -v taskset > /dev/null; then
  pin=(taskset -c "$core")
fi

echo "ray files and JSON in $work" >&2
RAYON_NUM_THREADS=1 "${pin[@]}" "$fissure" bench collision --backend cpu \
  --preset "$preset" --nodes "$nodes" --placement both --min-time-ms 1 \
  --min-repeats 1 --dump-rays "$work/rays" > /dev/null

for ((r = 1; r <= rounds; r++)); do
  for f in "$work"/rays/*.rays; do
    b="$(basename "$f" .rays)"
    echo "round $r/$rounds: $b" >&2
    "${pin[@]}" "$fissure" bench rays --threads 1 --min-time-ms "$min_time" --json "$f" \
      > "$work/fissure-$b-$r.json"
    "${pin[@]}" "$work/embree_rays" --min-time-ms "$min_time" "$f" \
      > "$work/embree-$b-$r.json" 2> "$work/embree-$b-$r.err"
  done
done

python3 - "$work" "$rounds" <<'PY'
import glob, json, os, statistics, subprocess, sys

work, rounds = sys.argv[1], int(sys.argv[2])
med = statistics.median
names = sorted(os.path.basename(f)[:-5] for f in glob.glob(f"{work}/rays/*.rays"))
cpu = "unknown CPU"
try:
    for line in open("/proc/cpuinfo"):
        if line.startswith("model name"):
            cpu = line.split(":", 1)[1].strip()
            break
except OSError:
    pass
ev = None
print(f"{rounds} interleaved rounds, medians; one thread each; {cpu}")
print()
print("| rays file | lines | fissure bounded | fissure bounded, per ray | Embree bounded (rtcIntersect1) | Embree bounded (rtcIntersect8) "
      "| fissure line | fissure line, per ray | Embree line (rtcIntersect1) | Embree line (rtcIntersect8) "
      "| fissure refit global | Embree refit global | fissure refit local | Embree refit (local bump) | answers: same / tie / other |")
print("|" + "---|" * 15)
for n in names:
    fs = [json.load(open(f"{work}/fissure-{n}-{r}.json"))[0] for r in range(1, rounds + 1)]
    es = [json.load(open(f"{work}/embree-{n}-{r}.json")) for r in range(1, rounds + 1)]
    ev = es[0]["embree_version"]
    f = lambda k: med(x[k] for x in fs)
    e = lambda k: med(x[k] for x in es) if all(x[k] is not None for x in es) else float("nan")
    print(f"| {n} | {fs[0]['rays']} "
          f"| {f('bounded_ns_per_line'):.0f} ns | {f('bounded_per_ray_ns_per_line'):.0f} ns "
          f"| {e('bounded_ns_per_line'):.0f} ns | {e('bounded8_ns_per_line'):.0f} ns "
          f"| {f('line_ns_per_line'):.0f} ns | {f('line_per_ray_ns_per_line'):.0f} ns "
          f"| {e('line_ns_per_line'):.0f} ns | {e('line8_ns_per_line'):.0f} ns "
          f"| {f('refit_global_ms'):.3f} ms | {e('refit_global_ms'):.3f} ms "
          f"| {f('refit_local_ms'):.3f} ms | {e('refit_local_ms'):.3f} ms "
          f"| {es[0]['same_triangles']} / {es[0]['differ_same_t']} / {es[0]['differ_other']} |")
print()
print(f"Embree {ev}; fissure: `fissure bench rays` (f64, watertight test, the server's tie rule).")
PY
