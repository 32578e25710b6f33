#!/usr/bin/env python3
"""`fissure mesh from-image` against nibabel's reading of the same files.

nibabel writes a sphere mask (radius 12 mm, defined in scanner space, so
an ellipsoid in voxel space when the voxels are not cubes) as NIfTI-1 and
NIfTI-2 files with an oblique affine (30 degrees about a tilted axis), a
flipped axis (negative determinant), the qform only, the sform only, gzip
or not, and one in metres. For each file this checks that

* `fissure mesh from-image FILE --out MESH.vtu` succeeds;
* every tetrahedron of the .vtu (read by meshio) is positively oriented and
  labelled 1;
* the mesh's centroid is within a fifth of a voxel of nibabel's
  `img.affine` applied to the sphere's centre in voxel coordinates (in
  metres): the reader and nibabel agree on where the image is;
* the volume is within `A (s / 4 + h^2 / (8 r))` of 4/3 pi r^3
  (`A = 4 pi r^2`, `s` the largest voxel size, `h` the spacing): the surface
  half-way between inside and outside voxel centres averages out to well
  within a quarter voxel, and the boundary triangles are chords of it at the
  spacing.

Usage: nifti_affines.py --fissure PATH_TO_fissure
Needs: nibabel, meshio, numpy.
"""

import argparse
import os
import subprocess
import sys
import tempfile

import meshio
import nibabel
import numpy as np

R_MM = 12.0
SPACING_MM = 2.0


def fail(message):
    print(f"nifti affines: FAILED: {message}", file=sys.stderr)
    sys.exit(1)


def rotation(axis, degrees):
    axis = np.asarray(axis, float)
    axis /= np.linalg.norm(axis)
    t = np.radians(degrees)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(t) * k + (1 - np.cos(t)) * k @ k


def affine(sizes, axis, degrees, flip, offset):
    lin = rotation(axis, degrees) @ np.diag(sizes)
    if flip:
        lin[:, 0] = -lin[:, 0]
    a = np.eye(4)
    a[:3, :3] = lin
    a[:3, 3] = offset
    return a


def sphere(dims, aff, centre_vox):
    """The mask of the ball of radius R_MM about aff @ centre_vox (mm)."""
    ijk = np.stack(np.meshgrid(*[np.arange(n) for n in dims], indexing="ij"), axis=-1)
    world = ijk @ aff[:3, :3].T + aff[:3, 3]
    centre = aff[:3, :3] @ centre_vox + aff[:3, 3]
    return (np.linalg.norm(world - centre, axis=-1) < R_MM).astype(np.uint8)


def write(path, version, data, aff, form, units="mm"):
    cls = nibabel.Nifti1Image if version == 1 else nibabel.Nifti2Image
    img = cls(data, None)
    if form in ("sform", "both"):
        img.set_sform(aff, code=2)
    else:
        img.set_sform(None, code=0)
    if form in ("qform", "both"):
        img.set_qform(aff, code=1)
    else:
        img.set_qform(None, code=0)
    img.header.set_xyzt_units(units)
    nibabel.save(img, path)


def tet_volumes(points, tets):
    a, b, c, d = (points[tets[:, k]] for k in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--fissure", required=True, help="path to the fissure binary")
    args = ap.parse_args()
    out = tempfile.mkdtemp(prefix="fissure-nifti-")
    oblique = affine([1.0, 1.2, 0.9], [1, 2, 3], 30.0, False, [40.0, -12.0, 7.5])
    flipped = affine([1.0, 1.0, 1.0], [0, 1, 1], 30.0, True, [-5.0, 9.0, -60.0])
    metres = affine([1.0, 1.0, 1.0], [2, -1, 1], 20.0, False, [10.0, 20.0, 30.0])
    cases = [
        # name, version, affine (mm), which form, extension, units
        ("oblique-sform-only", 1, oblique, "sform", ".nii", "mm"),
        ("oblique-nifti2", 2, oblique, "sform", ".nii", "mm"),
        ("oblique-both", 1, oblique, "both", ".nii.gz", "mm"),
        ("flipped-sform-only", 1, flipped, "sform", ".nii.gz", "mm"),
        ("flipped-qform-only", 1, flipped, "qform", ".nii", "mm"),
        ("flipped-qform-only-nifti2", 2, flipped, "qform", ".nii.gz", "mm"),
        ("oblique-qform-only", 1, oblique, "qform", ".nii", "mm"),
        ("metres-nifti2", 2, metres, "sform", ".nii", "meter"),
    ]
    dims = (32, 30, 34)
    centre_vox = np.array([15.7, 14.2, 16.45])
    worst = 0.0
    for name, version, aff, form, ext, units in cases:
        data = sphere(dims, aff, centre_vox)
        path = os.path.join(out, name + ext)
        written = aff.copy()
        if units == "meter":
            written[:3, :] *= 1e-3
        write(path, version, data, written, form, units)
        img = nibabel.load(path)
        if form == "qform" and int(img.header["sform_code"]) != 0:
            fail(f"{name}: nibabel wrote an sform")
        # nibabel's reading of where the image is, in metres.
        scale = 1.0 if units == "meter" else 1e-3
        centre = (img.affine[:3, :3] @ centre_vox + img.affine[:3, 3]) * scale
        sizes = np.linalg.norm(img.affine[:3, :3], axis=0) * scale
        vtu = os.path.join(out, name + ".vtu")
        cmd = [args.fissure, "mesh", "from-image", path, "--out", vtu,
               "--spacing-mm", str(SPACING_MM), "--levels", "1"]
        p = subprocess.run(cmd, capture_output=True, text=True)
        if p.returncode != 0:
            fail(f"{name}: exit {p.returncode}: {p.stdout}{p.stderr}")
        want_source = "sform" if form in ("sform", "both") else "qform"
        if f"affine from the {want_source}" not in p.stdout:
            fail(f"{name}: expected the {want_source}: {p.stdout}")
        mesh = meshio.read(vtu)
        points = mesh.points.astype(float)
        tets = mesh.cells_dict["tetra"]
        vols = tet_volumes(points, tets)
        if not (vols > 0).all():
            fail(f"{name}: {(vols <= 0).sum()} tetrahedra not positively oriented")
        labels = np.concatenate(mesh.cell_data["label"])
        if not (labels == 1).all():
            fail(f"{name}: labels {np.unique(labels)}")
        volume = vols.sum()
        centroid = (points[tets].mean(axis=1) * vols[:, None]).sum(axis=0) / volume
        r, h, s = R_MM * 1e-3, SPACING_MM * 1e-3, sizes.max()
        exact = 4.0 / 3.0 * np.pi * r ** 3
        bound = 4.0 * np.pi * r * r * (s / 4.0 + h * h / (8.0 * r))
        off = np.linalg.norm(centroid - centre)
        if off > 0.2 * s:
            fail(f"{name}: centre {centroid} is {off:.2e} m from nibabel's {centre}")
        if abs(volume - exact) > bound:
            fail(f"{name}: volume {volume:.4e} m^3 vs {exact:.4e} (bound {bound:.2e})")
        worst = max(worst, abs(volume / exact - 1.0))
        print(
            f"{name}: {len(points)} nodes, {len(tets)} tetrahedra, volume "
            f"{100 * (volume / exact - 1):+.2f}% (bound {100 * bound / exact:.2f}%), "
            f"centre {off / s:.3f} voxel from nibabel's"
        )
    print(f"nifti affines: OK ({len(cases)} files, worst volume error {100 * worst:.2f}%)")


if __name__ == "__main__":
    main()
