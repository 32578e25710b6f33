#!/usr/bin/env python3
"""A patient's brain from an image to a running demo: the MNI152 2009a grey
and white matter probability maps that nilearn's wheel ships.

The maps (nilearn/datasets/data/mni_icbm152_{gm,wm}_tal_nlin_sym_09a_converted
.nii.gz, uint8 0..255, 1 mm, sform) go through `fissure scene from-image`
with their sum thresholded at half its range (127.5) and the point
(-54, 15, -6) mm in the left Sylvian fissure; then `fissure demo` runs the
scene it wrote with both spatulas, and `fissure bench haptic` drives the
same trajectory with a full solve at every force sample. This checks that

* the mesh's volume is within 5 % of the thresholded voxels' volume that
  nibabel counts independently, and its grey and white tissue volumes are
  each within 10 % of nibabel's voxel counts of the voxels where that map
  is the larger;
* the fissure found opens laterally (its depth direction points to +x, into
  the left hemisphere, within 45 degrees) and its plane is closer to
  horizontal than vertical (the Sylvian fissure's stem), with a gap of at
  most 8 mm;
* both spatulas fit in the gap: no part of them is in the tissue at full
  insertion (the command turns the plane and narrows the plates until they
  fit), with the tips at least 5 mm past the entry;
* the scene runs: the demo finishes, both spatulas feel the tissue, and no
  point of the brain moves farther than twice the 2 mm push (a rigid plate
  pushes a wall about as far as it goes; before the plates were fitted in
  the gap they started in the tissue and the brain moved 1.2 m);
* every `fissure bench haptic` target is met on the scene (force samples
  against a full solve at every sample).

The force laws of a clean opening (the wall pushes back, never pulls, and
lets go after retraction) are checked on a synthetic slotted block
(client-cli/tests/cli/scene_from_image.rs).

Usage: mni_scene.py --fissure PATH_TO_fissure --wheel NILEARN_WHEEL [--keep DIR]
Needs: nibabel, numpy.
"""

import argparse
import csv
import os
import re
import subprocess
import sys
import tempfile
import time
import zipfile

import nibabel
import numpy as np

NEAR_MM = (-54.0, 15.0, -6.0)
PUSH_MM = 2.0


def fail(message):
    print(f"MNI scene: FAILED: {message}", file=sys.stderr)
    sys.exit(1)


def run(cmd):
    started = time.time()
    p = subprocess.run(cmd, capture_output=True, text=True)
    print(f"$ {' '.join(cmd)}  ({time.time() - started:.1f} s)")
    print(p.stdout)
    if p.returncode != 0:
        fail(f"exit {p.returncode}: {p.stderr[-3000:]}")
    return p.stdout


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--fissure", required=True, help="path to the fissure binary")
    ap.add_argument("--wheel", required=True, help="path to nilearn's wheel")
    ap.add_argument("--keep", help="write into this folder (kept) instead of a temporary one")
    args = ap.parse_args()
    out = args.keep or tempfile.mkdtemp(prefix="fissure-mni-")
    os.makedirs(out, exist_ok=True)
    wheel = zipfile.ZipFile(args.wheel)
    paths = []
    for tissue in ("gm", "wm"):
        name = f"mni_icbm152_{tissue}_tal_nlin_sym_09a_converted.nii.gz"
        path = os.path.join(out, name)
        with open(path, "wb") as f:
            f.write(wheel.read(f"nilearn/datasets/data/{name}"))
        paths.append(path)

    # Independent volumes: nibabel's voxels.
    gm, wm = (np.asarray(nibabel.load(p).dataobj, dtype=float) for p in paths)
    voxel_ml = abs(np.linalg.det(nibabel.load(paths[0]).affine[:3, :3])) / 1000.0
    brain = gm + wm > 127.5
    brain_ml = brain.sum() * voxel_ml
    grey_ml = (brain & (gm >= wm)).sum() * voxel_ml
    white_ml = (brain & (wm > gm)).sum() * voxel_ml

    scene_dir = os.path.join(out, "mni-sylvian")
    text = run(
        [args.fissure, "scene", "from-image", *paths, "--threshold", "127.5",
         "--fissure-near", *[str(v) for v in NEAR_MM], "--out", scene_dir]
    )
    m = re.search(r"mesh: .* ([0-9.]+) mL", text)
    if not m:
        fail("no mesh volume in the report")
    mesh_ml = float(m.group(1))
    if abs(mesh_ml - brain_ml) > 0.05 * brain_ml:
        fail(f"mesh volume {mesh_ml} mL against {brain_ml:.1f} mL of voxels")
    for label, ref in ((1, grey_ml), (2, white_ml)):
        m = re.search(rf"label {label}: ([0-9.]+) mL", text)
        if not m or abs(float(m.group(1)) - ref) > 0.10 * ref:
            fail(f"label {label}: {m and m.group(1)} mL against {ref:.1f} mL of voxels")
    m = re.search(
        r"fissure: entry .* along \(([-0-9.]+), ([-0-9.]+), ([-0-9.]+)\), gap ([0-9.]+) mm, "
        r"plane normal \(([-0-9.]+), ([-0-9.]+), ([-0-9.]+)\)",
        text,
    )
    if not m:
        fail("no fissure in the report")
    direction = np.array([float(m.group(i)) for i in (1, 2, 3)])
    gap_mm = float(m.group(4))
    normal = np.array([float(m.group(i)) for i in (5, 6, 7)])
    if direction[0] < np.cos(np.radians(45.0)):
        fail(f"the fissure's depth direction {direction} does not point into the left hemisphere")
    if abs(normal[2]) < np.sqrt(0.5):
        fail(f"the fissure's plane normal {normal} is not closer to vertical than horizontal")
    if gap_mm > 8.0:
        fail(f"gap {gap_mm} mm")
    if "lies in the tissue at full insertion" in text:
        fail("the spatulas do not fit in the gap")
    m = re.search(r"tips ([0-9.]+) mm past the entry", text)
    if not m or float(m.group(1)) < 5.0:
        fail(f"the tips reach {m and m.group(1)} mm past the entry (5 mm wanted)")

    demo_dir = os.path.join(out, "demo")
    run(
        [args.fissure, "demo", "--scene", os.path.join(scene_dir, "scene.toml"),
         "--trajectory", os.path.join(scene_dir, "open.csv"), "--out", demo_dir,
         "--no-pictures", "--quiet"]
    )
    summary = open(os.path.join(demo_dir, "summary.txt")).read()
    print(summary)
    for name in ("left", "right"):
        path = os.path.join(demo_dir, f"forces-{name}.csv")
        if not os.path.exists(path):
            fail(f"no {path}: {sorted(os.listdir(demo_dir))}")
        rows = list(csv.DictReader(open(path)))
        if len(rows) < 3000:
            fail(f"{name}: {len(rows)} force samples (the trajectory has 3101)")
        peak = max(
            (float(r["fx_n"]) ** 2 + float(r["fy_n"]) ** 2 + float(r["fz_n"]) ** 2) ** 0.5 for r in rows
        )
        if not peak > 0.0:
            fail(f"{name}: the spatula never met the tissue")
        print(f"{name}: peak force {peak:.4f} N")
    m = re.search(r"largest surface displacement: ([0-9.]+) mm", summary)
    if not m:
        fail("no largest displacement in the summary")
    if float(m.group(1)) > 2.0 * PUSH_MM:
        fail(f"the brain moved {m.group(1)} mm under a {PUSH_MM} mm push")

    import json
    bench = json.loads(run(
        [args.fissure, "bench", "haptic", "--scene", os.path.join(scene_dir, "scene.toml"),
         "--trajectory", os.path.join(scene_dir, "open.csv"), "--json", "--quiet"]
    ))
    for row in bench["runs"]:
        if row["targets_failed"]:
            fail(f"bench haptic misses {row['targets_failed']}: {json.dumps(row)[:2000]}")
        print(f"bench haptic: {row['samples']} samples, max error {row['max_error_rel']} of the peak, "
              f"ripple ratio {row['ripple_ratio']}: every target met")
    print("MNI scene: ok")


if __name__ == "__main__":
    main()
