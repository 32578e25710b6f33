"""An OpenIGTLink peer built on pyigtl, for client-cli/tests/cli/igtl_peers.rs.

Connects to the bridge, sends N TRANSFORMs packed by pyigtl (a press 2 mm
into the cube scene's top, in millimetres), and after each one reads
messages until the SENSOR answers of that pose (force and torque) are in.
Every message read has its header parsed by pyigtl and its body's CRC
checked with pyigtl's CRC-64; SENSOR and POLYDATA bodies (which pyigtl does
not decode) are read here from the OpenIGTLink layout. Prints one JSON
object. Usage: pyigtl_peer.py PORT N DEVICE
"""
import json
import socket
import struct
import sys

import numpy as np
import pyigtl
from pyigtl.messages import CRC64, MessageBase

HEADER = 58
TOUCH_Z_MM = 40.75  # the handle height at which face A touches the cube's top


def quat_to_matrix(w, x, y, z):
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def read_exact(sock, n):
    buf = b""
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        if not chunk:
            raise EOFError("the bridge closed the connection")
        buf += chunk
    return buf


def read_message(sock, report):
    header = read_exact(sock, HEADER)
    fields = MessageBase.parse_header(header)
    crc = struct.unpack(">Q", header[50:58])[0]
    body = read_exact(sock, fields["body_size"])
    if CRC64(body) != crc:
        report["crc_failures"] += 1
    return fields, body


def main():
    port, n, device = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
    rot = quat_to_matrix(0.5, -0.5, 0.5, 0.5)  # the plate flat, face A down
    sock = socket.create_connection(("127.0.0.1", port), timeout=30)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    report = {"crc_failures": 0, "sensors": [], "units": {}, "statuses": [], "polydata": []}
    base = 1_700_000_000.0
    for i in range(1, n + 1):
        t = i * 1e-3
        s = min(t / 0.1, 1.0)
        m = np.eye(4)
        m[:3, :3] = rot
        m[:3, 3] = (11.0, 5.0, TOUCH_Z_MM + 2.0 - 4.0 * s)
        msg = pyigtl.TransformMessage(m, timestamp=base + t, device_name=device)
        sock.sendall(msg.pack())
        got = {}
        while len(got) < 2:
            fields, body = read_message(sock, report)
            kind = fields["message_type"]
            if kind == "SENSOR":
                larray, _status, unit = struct.unpack(">BBQ", body[:10])
                values = struct.unpack(">%dd" % larray, body[10:])
                got[fields["device_name"]] = values
                report["units"][fields["device_name"]] = unit
                # The answer carries the pose's timestamp.
                if abs(fields["timestamp"] - (base + t)) > 1e-6:
                    report.setdefault("timestamp_mismatch", []).append(i)
            elif kind == "STATUS":
                code, subcode = struct.unpack(">Hq", body[:10])
                name = body[10:30].rstrip(b"\0").decode()
                text = body[30:].split(b"\0")[0].decode()
                report["statuses"].append([code, subcode, name, text])
            elif kind == "POLYDATA":
                report["polydata"].append(polydata_summary(body))
            else:
                report.setdefault("other", []).append(kind)
        report["sensors"].append(got)
    # Drain what is still coming (surfaces) for a moment.
    sock.settimeout(1.0)
    try:
        while True:
            fields, body = read_message(sock, report)
            if fields["message_type"] == "POLYDATA":
                report["polydata"].append(polydata_summary(body))
    except (socket.timeout, EOFError):
        pass
    sock.close()
    print(json.dumps(report))


def polydata_summary(body):
    h = struct.unpack(">10I", body[:40])
    npoints, npolygons, spolygons = h[0], h[5], h[6]
    points = np.frombuffer(body[40:40 + 12 * npoints], dtype=">f4").reshape(-1, 3)
    cells = np.frombuffer(body[40 + 12 * npoints:40 + 12 * npoints + spolygons], dtype=">u4")
    return {
        "npoints": npoints,
        "npolygons": npolygons,
        "first_cell": cells[:4].tolist(),
        "min_mm": points.min(axis=0).tolist(),
        "max_mm": points.max(axis=0).tolist(),
        "body_size": len(body),
    }


if __name__ == "__main__":
    main()
