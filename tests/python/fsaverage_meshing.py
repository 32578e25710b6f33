#!/usr/bin/env python3
"""A real cortex through `fissure mesh`: fsaverage5's pial and white surfaces.

The surfaces ship inside nilearn's wheel (nilearn/datasets/data/fsaverage5,
GIFTI, millimetres); nibabel reads them. For each surface this checks that

* `fissure mesh from-surface` refuses the file as it is (in millimetres),
  saying "this looks like millimetres: use --scale 0.001", before meshing;
* with `--scale 0.001` it meshes it at 3 mm, says whether and how it
  repaired a pinched boundary, and writes a mesh whose boundary is a closed
  manifold;
* `fissure mesh inspect --json` finds no problem in the result.

Usage: fsaverage_meshing.py --fissure PATH_TO_fissure --wheel NILEARN_WHEEL
Needs: nibabel, meshio.
"""

import argparse
import gzip
import json
import os
import subprocess
import sys
import tempfile
import zipfile

import meshio
import nibabel


def fail(message):
    print(f"fsaverage meshing: FAILED: {message}", file=sys.stderr)
    sys.exit(1)


def run(cmd):
    p = subprocess.run(cmd, capture_output=True, text=True)
    return p.returncode, p.stdout + p.stderr


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--fissure", required=True, help="path to the fissure binary")
    ap.add_argument("--wheel", required=True, help="path to nilearn's wheel")
    args = ap.parse_args()
    out = tempfile.mkdtemp(prefix="fissure-fsaverage-")
    wheel = zipfile.ZipFile(args.wheel)
    for name in ("pial_left", "white_left"):
        data = gzip.decompress(wheel.read(f"nilearn/datasets/data/fsaverage5/{name}.gii.gz"))
        gii = nibabel.GiftiImage.from_bytes(data)
        vertices = gii.darrays[0].data.astype(float)
        triangles = gii.darrays[1].data.astype(int)
        stl = os.path.join(out, f"{name}-mm.stl")
        meshio.write(stl, meshio.Mesh(vertices, [("triangle", triangles)]), binary=True)
        vtu = os.path.join(out, f"{name}.vtu")
        mesh = [args.fissure, "mesh", "from-surface", stl, "--out", vtu, "--resolution", "0.003"]
        code, text = run(mesh)
        if code == 0 or "this looks like millimetres: use --scale 0.001" not in text:
            fail(f"{name} in mm: exit {code}: {text}")
        code, text = run(mesh + ["--scale", "0.001"])
        if code != 0 or "the boundary is a closed manifold" not in text:
            fail(f"{name} with --scale 0.001: exit {code}: {text}")
        repaired = [line for line in text.splitlines() if line.startswith("repaired:")]
        code, text = run([args.fissure, "mesh", "inspect", vtu, "--json"])
        if code != 0:
            fail(f"inspect {name}: exit {code}: {text}")
        report = json.loads(text)
        if report["problems_found"] != 0:
            fail(f"{name}: {report['problems_found']} problems: {report['problems'][:5]}")
        print(
            f"{name}: {len(vertices)} vertices, {len(triangles)} triangles, refused in mm; "
            f"meshed with --scale 0.001: {report['nodes']} nodes, {report['tets']} tetrahedra, "
            f"0 problems; {repaired[0] if repaired else 'no repair needed'}"
        )
    print("fsaverage meshing: OK")


if __name__ == "__main__":
    main()
