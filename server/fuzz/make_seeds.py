#!/usr/bin/env python3
"""Writes the seed corpora of the fuzz targets into seeds/<target>/.

Seeds are the tool-written fixtures of server/tests/data, the scenes of
server/scenes, and small files of every form each reader accepts (a unit cube
split into five tetrahedra or its twelve boundary triangles), written here by
the format specifications. Run from server/fuzz: `python3 make_seeds.py`.
"""
import os
import shutil
import struct

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "..", "tests", "data")
SCENES = os.path.join(HERE, "..", "scenes")
SEEDS = os.path.join(HERE, "seeds")

NODES = [(x * 0.01, y * 0.01, z * 0.01) for z in (0, 1) for y in (0, 1) for x in (0, 1)]
# Five positive tetrahedra of the cube (0-based).
TETS = [(0, 1, 3, 5), (0, 3, 2, 6), (0, 5, 6, 4), (3, 6, 5, 7), (0, 3, 6, 5)]
TRIS = [
    (0, 2, 3), (0, 3, 1), (4, 5, 7), (4, 7, 6), (0, 1, 5), (0, 5, 4),
    (2, 6, 7), (2, 7, 3), (0, 4, 6), (0, 6, 2), (1, 3, 7), (1, 7, 5),
]


def put(target, name, data):
    d = os.path.join(SEEDS, target)
    os.makedirs(d, exist_ok=True)
    mode = "wb" if isinstance(data, bytes) else "w"
    with open(os.path.join(d, name), mode) as f:
        f.write(data)


def copy(target, src, name=None):
    d = os.path.join(SEEDS, target)
    os.makedirs(d, exist_ok=True)
    shutil.copy(src, os.path.join(d, name or os.path.basename(src)))


def msh22():
    s = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n%d\n" % len(NODES)
    s += "".join("%d %g %g %g\n" % (i + 1, *p) for i, p in enumerate(NODES))
    s += "$EndNodes\n$Elements\n%d\n" % (len(TETS) + 1)
    s += "1 15 2 0 1 1\n"
    s += "".join("%d 4 2 0 1 %d %d %d %d\n" % (i + 2, *(v + 1 for v in t)) for i, t in enumerate(TETS))
    return s + "$EndElements\n"


def msh41():
    s = "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n"
    s += "$Nodes\n1 %d 1 %d\n3 1 0 %d\n" % (len(NODES), len(NODES), len(NODES))
    s += "".join("%d\n" % (i + 1) for i in range(len(NODES)))
    s += "".join("%g %g %g\n" % p for p in NODES)
    s += "$EndNodes\n$Elements\n1 %d 1 %d\n3 1 4 %d\n" % (len(TETS), len(TETS), len(TETS))
    s += "".join("%d %d %d %d %d\n" % (i + 1, *(v + 1 for v in t)) for i, t in enumerate(TETS))
    return s + "$EndElements\n"


def vtk_ascii():
    s = "# vtk DataFile Version 4.2\nseed\nASCII\nDATASET UNSTRUCTURED_GRID\n"
    s += "POINTS %d double\n" % len(NODES) + "".join("%g %g %g\n" % p for p in NODES)
    s += "CELLS %d %d\n" % (len(TETS), 5 * len(TETS)) + "".join("4 %d %d %d %d\n" % t for t in TETS)
    s += "CELL_TYPES %d\n" % len(TETS) + "10\n" * len(TETS)
    return s


def vtk_binary42():
    b = b"# vtk DataFile Version 4.2\nseed\nBINARY\nDATASET UNSTRUCTURED_GRID\n"
    b += b"POINTS %d double\n" % len(NODES) + b"".join(struct.pack(">3d", *p) for p in NODES) + b"\n"
    b += b"CELLS %d %d\n" % (len(TETS), 5 * len(TETS))
    b += b"".join(struct.pack(">5i", 4, *t) for t in TETS) + b"\n"
    b += b"CELL_TYPES %d\n" % len(TETS) + struct.pack(">%di" % len(TETS), *[10] * len(TETS)) + b"\n"
    return b


def vtu_ascii():
    pts = " ".join("%g %g %g" % p for p in NODES)
    con = " ".join("%d %d %d %d" % t for t in TETS)
    off = " ".join(str(4 * (i + 1)) for i in range(len(TETS)))
    typ = " ".join("10" for _ in TETS)
    return (
        '<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="0.1" byte_order="LittleEndian">\n'
        '<UnstructuredGrid><Piece NumberOfPoints="%d" NumberOfCells="%d">\n'
        '<Points><DataArray type="Float64" NumberOfComponents="3" format="ascii">%s</DataArray></Points>\n'
        '<Cells><DataArray type="Int32" Name="connectivity" format="ascii">%s</DataArray>\n'
        '<DataArray type="Int32" Name="offsets" format="ascii">%s</DataArray>\n'
        '<DataArray type="UInt8" Name="types" format="ascii">%s</DataArray></Cells>\n'
        "</Piece></UnstructuredGrid></VTKFile>\n" % (len(NODES), len(TETS), pts, con, off, typ)
    )


def tetgen():
    node = "%d 3 0 0\n" % len(NODES) + "".join("%d %g %g %g\n" % (i, *p) for i, p in enumerate(NODES))
    ele = "%d 4 0\n" % len(TETS) + "".join("%d %d %d %d %d\n" % (i, *t) for i, t in enumerate(TETS))
    return node.encode() + b"\0" + ele.encode()


def obj():
    return "".join("v %g %g %g\n" % p for p in NODES) + "".join(
        "f %d %d %d\n" % tuple(v + 1 for v in t) for t in TRIS
    )


def ply_header(fmt):
    return (
        "ply\nformat %s 1.0\nelement vertex %d\nproperty float x\nproperty float y\nproperty float z\n"
        "element face %d\nproperty list uchar int vertex_indices\nend_header\n" % (fmt, len(NODES), len(TRIS))
    )


def ply_ascii():
    return ply_header("ascii") + "".join("%g %g %g\n" % p for p in NODES) + "".join(
        "3 %d %d %d\n" % t for t in TRIS
    )


def ply_binary():
    b = ply_header("binary_little_endian").encode()
    b += b"".join(struct.pack("<3f", *p) for p in NODES)
    b += b"".join(struct.pack("<B3i", 3, *t) for t in TRIS)
    return b


def normal(t):
    a, b, c = (NODES[i] for i in t)
    u = [b[k] - a[k] for k in range(3)]
    v = [c[k] - a[k] for k in range(3)]
    n = (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])
    m = sum(x * x for x in n) ** 0.5
    return tuple(x / m for x in n)


def stl_ascii():
    s = "solid seed\n"
    for t in TRIS:
        s += " facet normal %g %g %g\n  outer loop\n" % normal(t)
        s += "".join("   vertex %g %g %g\n" % NODES[i] for i in t)
        s += "  endloop\n endfacet\n"
    return s + "endsolid seed\n"


def stl_binary():
    b = b"seed".ljust(80, b" ") + struct.pack("<I", len(TRIS))
    for t in TRIS:
        b += struct.pack("<3f", *normal(t)) + b"".join(struct.pack("<3f", *NODES[i]) for i in t) + b"\0\0"
    return b


def varint(n):
    out = b""
    while True:
        byte = n & 0x7F
        n >>= 7
        if n:
            out += bytes([byte | 0x80])
        else:
            return out + bytes([byte])


def field_double(k, x):
    return varint(k << 3 | 1) + struct.pack("<d", x)


def field_msg(k, body):
    return varint(k << 3 | 2) + varint(len(body)) + body


def pose(t, seq, p, q):
    body = field_double(1, t) + varint(2 << 3) + varint(seq)
    body += field_msg(3, b"".join(field_double(i + 1, x) for i, x in enumerate(p)))
    body += field_msg(4, b"".join(field_double(i + 1, x) for i, x in enumerate(q)))
    return body


def delimited(msgs):
    return b"".join(varint(len(m)) + m for m in msgs)


# The bridge's datagrams (client-cli/src/client/bridge.rs, "Datagram format"),
# packed here from the documented layout.
POSE_FMT = "<4sBBHQd3d4d"  # 80 bytes
FORCE_FMT = "<4sBBHQd3d3dIIQddQ"  # 112 bytes
FLAT_DOWN = (0.5, -0.5, 0.5, 0.5)


def bin_pose(i, seq, t, p, q, magic=b"FSP1", version=1, reserved=0):
    return struct.pack(POSE_FMT, magic, version, i, reserved, seq, t, *p, *q)


def bin_force(i, status, seq, t, f, tq, contacts, flags, frame, age, us):
    return struct.pack(FORCE_FMT, b"FSF1", 1, i, status, seq, t, *f, *tq, contacts, flags, frame, age, us, 0)


def json_pose(name, seq, t, p, q, key="instrument"):
    who = '"%s":"%s"' % (key, name) if key == "instrument" else '"i":%d' % name
    return '{%s,"seq":%d,"t_s":%r,"p":[%r,%r,%r],"q":[%r,%r,%r,%r]}' % (who, seq, t, *p, *q)


def bridge_seeds():
    nan, inf = float("nan"), float("inf")
    assert struct.calcsize(POSE_FMT) == 80 and struct.calcsize(FORCE_FMT) == 112
    # A press 2 mm into the cube's top (the bridge test's trajectory).
    for k, i in enumerate((1, 50, 100)):
        t = i * 1e-3
        z = 0.04 + 0.00075 + 0.002 - 0.004 * min(t / 0.1, 1.0)
        put("bridge", "press-%d.bin" % k, bin_pose(0, i, t, (0.011, 0.005, z), FLAT_DOWN))
    put("bridge", "right.bin", bin_pose(1, 7, 0.007, (-0.011, 0.005, 0.045), (1.0, 0.0, 0.0, 0.0)))
    put("bridge", "extremes.bin", bin_pose(255, 2**64 - 1, 1.7976931348623157e308, (5e-324, -0.0, 1e-300), (1.0, 0.0, 0.0, 0.0)))
    put("bridge", "nan.bin", bin_pose(0, 2, nan, (nan, inf, -inf), (nan, 0.0, 0.0, 0.0)))
    put("bridge", "zero-quat.bin", bin_pose(0, 3, 0.003, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0)))
    put("bridge", "non-unit.bin", bin_pose(0, 4, 0.004, (0.0, 0.0, 0.0), (2.0, 0.0, 0.0, 0.0)))
    put("bridge", "reserved.bin", bin_pose(0, 5, 0.005, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), reserved=0xFFFF))
    put("bridge", "version-2.bin", bin_pose(0, 6, 0.006, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), version=2))
    good = bin_pose(0, 8, 0.008, (0.011, 0.005, 0.04275), FLAT_DOWN)
    put("bridge", "truncated.bin", good[:79])
    put("bridge", "header-only.bin", good[:8])
    put("bridge", "long.bin", good + b"\0")
    put("bridge", "oversized.bin", good + b"\0" * (1025 - len(good)))
    put("bridge", "force.bin", bin_force(0, 0, 8, 0.008, (0.01, -0.02, 0.35), (0.0, 1e-4, 0.0), 5, 0, 12, 0.004, 41.0))
    put("bridge", "force-rejected.bin", bin_force(1, 1, 9, 0.009, (0.0,) * 3, (0.0,) * 3, 0, 2, 0, 0.0, 3.5))
    put("bridge", "empty", b"")
    put("bridge", "blank", b" \t\r\n")
    put("bridge", "named.json", json_pose("left", 7, 0.007, (0.011, 0.005, 0.04275), FLAT_DOWN) + "\n")
    put("bridge", "index.json", "  " + json_pose(1, 8, 0.008, (-0.011, 0.005, 0.045), (1.0, 0.0, 0.0, 0.0), key="i"))
    put("bridge", "both.json", '{"instrument":"left","i":0,"seq":1,"t_s":0,"p":[0,0,0],"q":[1,0,0,0]}')
    put("bridge", "neither.json", '{"seq":1,"t_s":0,"p":[0,0,0],"q":[1,0,0,0]}')
    put("bridge", "unknown-field.json", '{"i":0,"seq":1,"t_s":0,"p":[0,0,0],"q":[1,0,0,0],"v":1}')
    put("bridge", "nan.json", '{"i":0,"seq":1,"t_s":NaN,"p":[0,0,0],"q":[1,0,0,0]}')
    put("bridge", "overflow.json", '{"i":0,"seq":18446744073709551616,"t_s":1e400,"p":[0,0,0],"q":[1,0,0,0]}')
    put("bridge", "escaped-name.json", '{"instrument":"le\\"ft","seq":1,"t_s":0,"p":[0,0,0],"q":[1,0,0,0]}')
    put("bridge", "null-index.json", '{"instrument":"left","i":null,"seq":1,"t_s":0,"p":[0,0,0],"q":[1,0,0,0]}')
    # Long digit strings (serde_json's default float reader rounds them
    # differently from Rust's shortest round-trip printing).
    put("bridge", "long-digits.json", '{"instrument":"right","seq":9,"t_s":0.0332222222222222222222222222222222222222E43,"p":[0.0,0.0,0.0],"q":[1.0,0.0,0.0,0.0]}')
    put("bridge", "padded.json", json_pose("right", 9, 0.009, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0)).ljust(1024))


# OpenIGTLink messages (client-cli/src/client/bridge/igtl/codec.rs), packed here
# from the protocol's layout. File names: `ok-*` parse; `bad-<cause>-*` are
# refused with that cause (`IgtlError::kind`), which
# client-cli/tests/cli/igtl_corpus.rs checks.
def crc64(data):
    crc = 0
    for b in data:
        crc ^= b << 56
        for _ in range(8):
            crc = ((crc << 1) ^ 0x42F0E1EBA9EA3693) if crc & (1 << 63) else crc << 1
            crc &= (1 << 64) - 1
    return crc


def igtl(kind, device, body, version=1, ts=0, crc=None, size=None):
    head = struct.pack(">H12s20sQQQ", version, kind, device, ts,
                       len(body) if size is None else size,
                       crc64(body) if crc is None else crc)
    return head + body


def transform_body(r, t):
    cols = [r[row][col] for col in range(3) for row in range(3)]
    return struct.pack(">12f", *cols, *t)


def polydata_body(points, polys, strips=(), attrs=b"", nattr=0):
    pc = [v for c in polys for v in (len(c), *c)]
    sc = [v for c in strips for v in (len(c), *c)]
    head = struct.pack(">10I", len(points), 0, 0, 0, 0, len(polys), 4 * len(pc), len(strips), 4 * len(sc), nattr)
    pts = b"".join(struct.pack(">3f", *p) for p in points)
    return head + pts + struct.pack(">%dI" % len(pc), *pc) + struct.pack(">%dI" % len(sc), *sc) + attrs


def nifti(version, dims, affine, code_field="sform", datatype=2, big=False, gz=False):
    """A NIfTI-1 (348-byte header) or NIfTI-2 (540) image of uint8 or
    float32 voxels, the voxel values a ball; sform or qform (identity
    rotation) gives the affine."""
    import gzip
    e = ">" if big else "<"
    nx, ny, nz = dims
    size = {2: 1, 16: 4}[datatype]
    voxels = bytearray()
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                inside = (i - nx / 2) ** 2 + (j - ny / 2) ** 2 + (k - nz / 2) ** 2 < (nx / 3) ** 2
                voxels += struct.pack(e + ("B" if datatype == 2 else "f"), 1 if inside else 0)
    if version == 1:
        h = bytearray(352)
        struct.pack_into(e + "i", h, 0, 348)
        struct.pack_into(e + "8h", h, 40, 3, nx, ny, nz, 1, 1, 1, 1)
        struct.pack_into(e + "hh", h, 70, datatype, 8 * size)
        struct.pack_into(e + "8f", h, 76, 1.0, 1.0, 1.0, 1.0, 0, 0, 0, 0)
        struct.pack_into(e + "fff", h, 108, 352.0, 1.0, 0.0)
        h[123] = 2
        if code_field == "sform":
            struct.pack_into(e + "hh", h, 252, 0, 1)
            for r in range(3):
                struct.pack_into(e + "4f", h, 280 + 16 * r, *affine[r])
        else:
            struct.pack_into(e + "hh", h, 252, 1, 0)
            struct.pack_into(e + "6f", h, 256, 0, 0, 0, *[affine[r][3] for r in range(3)])
        h[344:348] = b"n+1\0"
    else:
        h = bytearray(544)
        struct.pack_into(e + "i", h, 0, 540)
        h[4:12] = b"n+2\0\r\n\x1a\n"
        struct.pack_into(e + "hh", h, 12, datatype, 8 * size)
        struct.pack_into(e + "8q", h, 16, 3, nx, ny, nz, 1, 1, 1, 1)
        struct.pack_into(e + "8d", h, 104, 1.0, 1.0, 1.0, 1.0, 0, 0, 0, 0)
        struct.pack_into(e + "qdd", h, 168, 544, 1.0, 0.0)
        if code_field == "sform":
            struct.pack_into(e + "ii", h, 344, 0, 1)
            for r in range(3):
                struct.pack_into(e + "4d", h, 400 + 32 * r, *affine[r])
        else:
            struct.pack_into(e + "ii", h, 344, 1, 0)
            struct.pack_into(e + "6d", h, 352, 0, 0, 0, *[affine[r][3] for r in range(3)])
        struct.pack_into(e + "i", h, 500, 2)
    data = bytes(h) + bytes(voxels)
    return gzip.compress(data) if gz else data


def nifti_seeds():
    a = [[1.0, 0, 0, -4.0], [0, 1.0, 0, -4.0], [0, 0, 1.0, -4.0]]
    oblique = [[0.866, -0.5, 0, -3.0], [0.5, 0.866, 0, -5.0], [0, 0, -1.0, 4.0]]
    put("nifti", "ball-1.nii", nifti(1, (8, 8, 8), a))
    put("nifti", "ball-1-qform-f32-big.nii", nifti(1, (6, 7, 5), a, "qform", 16, big=True))
    put("nifti", "ball-1-oblique.nii.gz", nifti(1, (8, 8, 8), oblique, gz=True))
    put("nifti", "ball-2.nii", nifti(2, (8, 8, 8), a))
    put("nifti", "ball-2-qform-f32.nii.gz", nifti(2, (5, 6, 7), a, "qform", 16, gz=True))


def igtl_seeds():
    eye = ((1, 0, 0), (0, 1, 0), (0, 0, 1))
    rz = ((0, -1, 0), (1, 0, 0), (0, 0, 1))
    ts = (1_700_000_000 << 32) | 0x80000000
    good = igtl(b"TRANSFORM", b"Tracker", transform_body(eye, (11.0, 5.0, 42.75)), ts=ts)
    put("igtl", "ok-transform.bin", good)
    put("igtl", "ok-transform-rotated.bin", igtl(b"TRANSFORM", b"left", transform_body(rz, (-11.0, 5.0, 45.0))))
    v2 = struct.pack(">HHII", 12, 10, 4, 7) + transform_body(eye, (1.0, 2.0, 3.0)) + b"\x00\x01\x00\x03\x00\x03\x00\x00\x00\x01key1"
    put("igtl", "ok-transform-v2-metadata.bin", igtl(b"TRANSFORM", b"Tracker", v2, version=2))
    put("igtl", "ok-position-28.bin", igtl(b"POSITION", b"Stylus", struct.pack(">7f", 1, 2, 3, 0, 0, 0.6, 0.8)))
    put("igtl", "ok-position-24.bin", igtl(b"POSITION", b"Stylus", struct.pack(">6f", 1, 2, 3, 0, 0, 0.6)))
    put("igtl", "ok-position-12.bin", igtl(b"POSITION", b"Stylus", struct.pack(">3f", 1, 2, 3)))
    newton = (0x0B << 4 | 1) << 50
    put("igtl", "ok-sensor-force.bin", igtl(b"SENSOR", b"left_force", struct.pack(">BBQ3d", 3, 0, newton, 0.01, -0.02, 0.35)))
    put("igtl", "ok-status.bin", igtl(b"STATUS", b"left", struct.pack(">Hq20s", 2, 3, b"POSE_REJECTED") + b"position is NaN\0"))
    square = [(0, 0, 0), (10, 0, 0), (0, 10, 0), (10, 10, 5)]
    put("igtl", "ok-polydata.bin", igtl(b"POLYDATA", b"fissure_surface", polydata_body(square, [(0, 1, 2), (1, 3, 2)], [(0, 1, 2, 3)])))
    attr = struct.pack(">BBI", 0, 1, 4) + b"disp\0\0" + struct.pack(">4f", 0, 0.1, 0.2, 0.3)
    put("igtl", "ok-polydata-attribute.bin", igtl(b"POLYDATA", b"fissure_surface", polydata_body(square, [(0, 1, 2)], attrs=attr, nattr=1)))
    # Malformed headers.
    put("igtl", "bad-short-header-empty.bin", b"")
    put("igtl", "bad-short-header-57.bin", good[:57])
    put("igtl", "bad-version-0.bin", b"\x00\x00" + good[2:])
    put("igtl", "bad-version-3.bin", b"\x00\x03" + good[2:])
    put("igtl", "bad-type-name-empty.bin", good[:2] + b"\0" * 12 + good[14:])
    put("igtl", "bad-type-name-binary.bin", good[:2] + b"TRANS\xffFORM\0\0\0" + good[14:])
    put("igtl", "bad-device-name-after-nul.bin", good[:14] + b"Tracker\0\0\0x" + b"\0" * 9 + good[34:])
    huge = bytearray(good)
    huge[42:50] = struct.pack(">Q", 2**64 - 1)
    put("igtl", "bad-body-too-large.bin", bytes(huge))
    # Bodies that do not match their header.
    put("igtl", "bad-body-length-beyond-data.bin", igtl(b"TRANSFORM", b"Tracker", transform_body(eye, (0, 0, 0)), size=4096))
    put("igtl", "bad-body-length-trailing.bin", good + b"\0")
    put("igtl", "bad-crc-flipped.bin", igtl(b"TRANSFORM", b"Tracker", transform_body(eye, (0, 0, 0)), crc=crc64(transform_body(eye, (0, 0, 0))) ^ 1))
    put("igtl", "bad-crc-zero.bin", igtl(b"TRANSFORM", b"Tracker", transform_body(eye, (1, 0, 0)), crc=0))
    put("igtl", "bad-extended-header-sizes.bin", igtl(b"TRANSFORM", b"Tracker", struct.pack(">HHII", 12, 0, 4000, 0) + transform_body(eye, (0, 0, 0)), version=2))
    put("igtl", "bad-extended-header-short.bin", igtl(b"TRANSFORM", b"Tracker", b"\0\x0c", version=2))
    # Types the bridge does not read.
    put("igtl", "bad-unknown-type-get-status.bin", igtl(b"GET_STATUS", b"", b""))
    put("igtl", "bad-unknown-type-image.bin", igtl(b"IMAGE", b"US", b"\0" * 72))
    # Bodies that do not hold what they say.
    put("igtl", "bad-content-length-transform.bin", igtl(b"TRANSFORM", b"Tracker", transform_body(eye, (0, 0, 0))[:44]))
    put("igtl", "bad-content-length-position.bin", igtl(b"POSITION", b"Stylus", struct.pack(">5f", 1, 2, 3, 0, 0)))
    put("igtl", "bad-not-finite-transform.bin", igtl(b"TRANSFORM", b"Tracker", transform_body(eye, (float("nan"), 0, 0))))
    put("igtl", "bad-not-rotation-scaled.bin", igtl(b"TRANSFORM", b"Tracker", transform_body(((2, 0, 0), (0, 1, 0), (0, 0, 1)), (0, 0, 0))))
    put("igtl", "bad-not-rotation-mirror.bin", igtl(b"TRANSFORM", b"Tracker", transform_body(((-1, 0, 0), (0, 1, 0), (0, 0, 1)), (0, 0, 0))))
    put("igtl", "bad-sensor-length.bin", igtl(b"SENSOR", b"s", struct.pack(">BBQ2d", 3, 0, newton, 1, 2)))
    put("igtl", "bad-status-no-nul.bin", igtl(b"STATUS", b"s", struct.pack(">Hq20s", 1, 0, b"OK") + b"no end"))
    # Huge or inconsistent POLYDATA.
    put("igtl", "bad-polydata-huge-counts.bin", igtl(b"POLYDATA", b"b", struct.pack(">10I", 2**32 - 1, 0, 0, 0, 0, 2**32 - 1, 2**32 - 4, 0, 0, 2**32 - 1)))
    put("igtl", "bad-polydata-index-out-of-range.bin", igtl(b"POLYDATA", b"b", polydata_body(square, [(0, 1, 9)])))
    put("igtl", "bad-polydata-cell-past-end.bin", igtl(b"POLYDATA", b"b", polydata_body(square, [(0, 1, 2)])[:-4]))
    body = bytearray(polydata_body(square, [(0, 1, 2)]))
    body[20:24] = struct.pack(">I", 2)
    put("igtl", "bad-polydata-cell-count.bin", igtl(b"POLYDATA", b"b", bytes(body)))
    put("igtl", "bad-polydata-attribute-type.bin", igtl(b"POLYDATA", b"b", polydata_body(square, [(0, 1, 2)], attrs=struct.pack(">BBI", 7, 1, 4) + b"a\0" + struct.pack(">4f", 0, 0, 0, 0), nattr=1)))
    put("igtl", "bad-polydata-nan-point.bin", igtl(b"POLYDATA", b"b", polydata_body([(float("nan"), 0, 0)], [])))


def main():
    if os.path.isdir(SEEDS):
        shutil.rmtree(SEEDS)
    copy("msh", os.path.join(DATA, "gmsh-box-41.msh"))
    copy("msh", os.path.join(DATA, "gmsh-box-22-bin.msh"))
    put("msh", "cube-22.msh", msh22())
    put("msh", "cube-41.msh", msh41())
    copy("vtk", os.path.join(DATA, "meshio-51-bin.vtk"))
    put("vtk", "cube-ascii.vtk", vtk_ascii())
    put("vtk", "cube-42-bin.vtk", vtk_binary42())
    copy("vtu", os.path.join(DATA, "meshio-zlib.vtu"))
    put("vtu", "cube-ascii.vtu", vtu_ascii())
    with open(os.path.join(DATA, "tetgen-block.1.node"), "rb") as f:
        node = f.read()
    with open(os.path.join(DATA, "tetgen-block.1.ele"), "rb") as f:
        ele = f.read()
    put("tetgen", "tetgen-block.1", node + b"\0" + ele)
    put("tetgen", "cube.0", tetgen())
    put("obj", "cube.obj", obj())
    put("ply", "cube-ascii.ply", ply_ascii())
    put("ply", "cube-binary.ply", ply_binary())
    put("stl", "cube-ascii.stl", stl_ascii())
    put("stl", "cube-binary.stl", stl_binary())
    for name in sorted(os.listdir(SCENES)):
        copy("scene", os.path.join(SCENES, name))
    q = (0.5, -0.5, 0.5, 0.5)
    put("pose", "one", delimited([pose(0.0, 1, (0.011, 0.005, 0.04275), q)]))
    put("pose", "stream", delimited([pose(i * 1e-3, i + 1, (0.011, 0.005, 0.04275 - i * 1e-4), q) for i in range(8)]))
    put("pose", "bad", delimited([
        pose(0.0, 1, (float("nan"), 0.0, 0.0), q),
        pose(0.0, 2, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0)),
        pose(0.002, 3, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0)),
        pose(0.001, 4, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0)),
        pose(0.003, 3, (1.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0)),
    ]))
    bridge_seeds()
    igtl_seeds()
    nifti_seeds()


if __name__ == "__main__":
    main()
