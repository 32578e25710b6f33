#!/usr/bin/env python3
"""Compares two fissure study output folders: grid.csv, stability.csv and
study.json must hold the same values, byte for byte, except the measured
times (wall-clock measurements of the machine, which no two runs share).

usage: compare_outputs.py A B [--files grid.csv,stability.csv,study.json]
Exits 1 naming the first differences, 0 when equal.
"""
import csv
import json
import sys

# The measured times: every other column and key must be equal.
TIMING = {
    "ms_per_step",
    "collision_ms",
    "us_per_sample",
    "us_per_sample_p99",
    "setup_ms",
    "total_s",
}


def csv_rows(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    header = rows[0]
    keep = [i for i, name in enumerate(header) if name not in TIMING]
    return [[r[i] for i in keep] for r in rows], [header[i] for i in keep]


def strip(value):
    if isinstance(value, dict):
        return {k: strip(v) for k, v in value.items() if k not in TIMING}
    if isinstance(value, list):
        return [strip(v) for v in value]
    return value


def compare_csv(a, b, name):
    (ra, ha), (rb, _) = csv_rows(a), csv_rows(b)
    diffs = []
    if len(ra) != len(rb):
        diffs.append(f"{name}: {len(ra) - 1} rows against {len(rb) - 1}")
    for n, (x, y) in enumerate(zip(ra, rb)):
        for col, (u, v) in enumerate(zip(x, y)):
            if u != v:
                diffs.append(f"{name} row {n} ({x[0]}) column {ha[col]}: {u!r} != {v!r}")
    return diffs


def compare_json(a, b, name):
    # parse_float=str keeps each number's text: equal text is equal bits.
    with open(a) as f:
        ja = strip(json.load(f, parse_float=str))
    with open(b) as f:
        jb = strip(json.load(f, parse_float=str))
    da = json.dumps(ja, sort_keys=True, indent=1).splitlines()
    db = json.dumps(jb, sort_keys=True, indent=1).splitlines()
    if da == db:
        return []
    import difflib

    return [f"{name}: " + line for line in list(difflib.unified_diff(da, db, lineterm="", n=1))[:40]]


def main():
    args = sys.argv[1:]
    files = ["grid.csv", "stability.csv", "study.json"]
    if "--files" in args:
        i = args.index("--files")
        files = args[i + 1].split(",")
        del args[i : i + 2]
    if len(args) != 2:
        print(__doc__, file=sys.stderr)
        return 2
    a, b = args
    diffs = []
    for name in files:
        fa, fb = f"{a}/{name}", f"{b}/{name}"
        if name.endswith(".csv"):
            diffs += compare_csv(fa, fb, name)
        else:
            diffs += compare_json(fa, fb, name)
    if diffs:
        print(f"{a} and {b} differ beyond the measured times:", file=sys.stderr)
        for d in diffs[:60]:
            print("  " + d, file=sys.stderr)
        return 1
    print(f"{a} and {b}: {', '.join(files)} equal but for the measured times ({', '.join(sorted(TIMING))})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
