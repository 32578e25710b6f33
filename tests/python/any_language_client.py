#!/usr/bin/env python3
"""A client of fissure.v1 in another language, generated from the proto alone.

Generates Python code from proto/fissure/v1/fissure.proto with grpcio-tools,
starts the `fissure-server` binary on the cube scene with a token, and checks
what a client written from the contract expects:

* grpc.health.v1 reports SERVING for "" and "fissure.v1.Fissure" once the
  scene is loaded (it waits for that, as a probe would);
* reflection (grpcio-reflection's client, which speaks v1alpha) lists the
  service, resolves its file, and answers an unknown symbol without losing
  the stream;
* GetScene describes the cube in SI units;
* Reset without the token is UNAUTHENTICATED, with it (scheme in lower case)
  it returns a frame number;
* a Haptic stream claiming `left` answers every pose once, in order, with a
  force that pushes the spatula out of the tissue when it presses 2 mm in;
* a Watch stream receives frames with the positions of every surface vertex;
* SIGTERM ends the server with exit status 0.

Usage: any_language_client.py --server PATH_TO_fissure-server [--proto-root proto]
Needs: grpcio, grpcio-tools, grpcio-health-checking, grpcio-reflection.
"""

import argparse
import importlib
import os
import queue
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time

import grpc
from grpc_health.v1 import health_pb2, health_pb2_grpc
from grpc_reflection.v1alpha.proto_reflection_descriptor_database import (
    ProtoReflectionDescriptorDatabase,
)
from grpc_tools import protoc

TOKEN = "any-language-token"
# Lays the plate flat, face A down, tip towards +y (see cube.toml).
FLAT_DOWN = (0.5, -0.5, 0.5, 0.5)
# Handle height at which face A touches the cube's top (z = 40 mm), m.
TOUCH_Z = 0.04 + 0.00075
LEFT = (0.011, 0.005)


def fail(message):
    print(f"any-language client: FAILED: {message}", file=sys.stderr)
    sys.exit(1)


def check(condition, message):
    if not condition:
        fail(message)


def generate(proto_root, out):
    """Python modules from the proto, as a client in any language would."""
    rc = protoc.main(
        [
            "grpc_tools.protoc",
            f"-I{proto_root}",
            f"--python_out={out}",
            f"--grpc_python_out={out}",
            os.path.join(proto_root, "fissure", "v1", "fissure.proto"),
        ]
    )
    check(rc == 0, f"protoc failed with {rc}")
    sys.path.insert(0, out)
    pb = importlib.import_module("fissure.v1.fissure_pb2")
    grpc_pb = importlib.import_module("fissure.v1.fissure_pb2_grpc")
    return pb, grpc_pb


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_serving(channel, deadline_s):
    health = health_pb2_grpc.HealthStub(channel)
    seen = []
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        try:
            statuses = [
                health.Check(health_pb2.HealthCheckRequest(service=name), timeout=2).status
                for name in ("", "fissure.v1.Fissure")
            ]
        except grpc.RpcError as e:
            statuses = [e.code()]
        seen.append(statuses)
        if statuses == [health_pb2.HealthCheckResponse.SERVING] * 2:
            return seen
        time.sleep(0.05)
    fail(f"not SERVING within {deadline_s} s: {seen[-3:]}")


def pose(pb, t, seq, z):
    return pb.PoseSample(
        t_s=t,
        sequence=seq,
        position_m=pb.Vec3(x=LEFT[0], y=LEFT[1], z=z),
        orientation=pb.Quaternion(w=FLAT_DOWN[0], x=FLAT_DOWN[1], y=FLAT_DOWN[2], z=FLAT_DOWN[3]),
    )


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--server", required=True, help="path to the fissure-server binary")
    ap.add_argument("--proto-root", default="proto")
    args = ap.parse_args()

    out = tempfile.mkdtemp(prefix="fissure-py-")
    pb, grpc_pb = generate(args.proto_root, out)

    port = free_port()
    server = subprocess.Popen(
        [
            args.server,
            "--scene",
            "cube",
            "--listen",
            f"127.0.0.1:{port}",
            "--token",
            TOKEN,
            "--force-loop-rt-priority",
            "0",
            "--transport-rt-priority",
            "0",
            "--log",
            "warn",
        ],
    )
    try:
        channel = grpc.insecure_channel(f"127.0.0.1:{port}")
        grpc.channel_ready_future(channel).result(timeout=30)
        seen = wait_serving(channel, 60)
        print(f"health: SERVING for '' and fissure.v1.Fissure after {len(seen)} probes")

        db = ProtoReflectionDescriptorDatabase(channel)
        services = list(db.get_services())
        check("fissure.v1.Fissure" in services, f"reflection lists {services}")
        try:
            db.FindFileContainingSymbol("fissure.v1.NoSuchThing")
            fail("an unknown symbol was found")
        except KeyError:
            pass
        fd = db.FindFileContainingSymbol("fissure.v1.Fissure.Haptic")
        check(fd.name == "fissure/v1/fissure.proto", f"reflection file {fd.name}")
        print(f"reflection: {services}; unknown symbol answered in-band, stream kept")

        stub = grpc_pb.FissureStub(channel)
        scene = stub.GetScene(pb.GetSceneRequest(), timeout=5)
        check(scene.name == "cube" and scene.units == "SI", f"scene {scene.name} {scene.units}")
        check(
            [i.name for i in scene.instruments] == ["left", "right"],
            f"instruments {[i.name for i in scene.instruments]}",
        )
        n_vertices = scene.model.surface_vertices

        try:
            stub.Reset(pb.ResetRequest(), timeout=5)
            fail("Reset without the token was accepted")
        except grpc.RpcError as e:
            check(e.code() == grpc.StatusCode.UNAUTHENTICATED, f"Reset without token: {e.code()}")
        frame = stub.Reset(
            pb.ResetRequest(), metadata=[("authorization", f"bearer {TOKEN}")], timeout=5
        ).frame
        print(f"reset: UNAUTHENTICATED without the token; with it, frame {frame}")

        frames = queue.Queue()
        watch = stub.Watch(pb.WatchRequest(include_positions=True))

        def read_frames():
            try:
                for f in watch:
                    frames.put(f)
            except grpc.RpcError:
                pass

        reader = threading.Thread(target=read_frames, daemon=True)
        reader.start()

        # 1,200 poses 1 ms apart: 100 above the cube, a 2 mm press over 100,
        # then held for a second (deformation steps follow on the wall clock).
        poses = []
        for k in range(1200):
            z = TOUCH_Z + 0.001 if k < 100 else TOUCH_Z - min(k - 100, 100) / 100 * 0.002
            poses.append(pose(pb, k * 0.001, k + 1, z))
        answers = queue.Queue()
        requests = queue.Queue()

        def pose_iter():
            while True:
                p = requests.get()
                if p is None:
                    return
                yield p

        stream = stub.Haptic(
            pose_iter(),
            metadata=[("fissure-instrument", "left"), ("authorization", f"Bearer {TOKEN}")],
        )
        start = time.monotonic()
        for p in poses:
            time.sleep(max(0.0, start + p.t_s - time.monotonic()))
            requests.put(p)
            answers.put(next(stream))
        requests.put(None)
        rest = list(stream)
        check(not rest, f"{len(rest)} answers after the last pose")
        got = [answers.get() for _ in range(answers.qsize())]
        check(len(got) == len(poses), f"{len(got)} answers to {len(poses)} poses")
        check(
            [a.sequence for a in got] == [p.sequence for p in poses],
            "answers out of order or missing",
        )
        rejected = [a for a in got if a.HasField("rejection")]
        check(not rejected, f"rejections: {rejected[:1]}")
        last = got[-1]
        check(last.force_n.z > 0.01 and last.contact_count > 0, f"pressed sample {last}")
        print(
            f"haptic: {len(got)} answers in order; pressed 2 mm: F_z = {last.force_n.z:.3f} N, "
            f"{last.contact_count} contacts"
        )

        end = time.monotonic() + 10
        with_positions = 0
        while time.monotonic() < end and with_positions < 3:
            try:
                f = frames.get(timeout=0.5)
            except queue.Empty:
                continue
            if len(f.positions_m) == 3 * n_vertices:
                with_positions += 1
        check(with_positions >= 3, f"{with_positions} frames with positions")
        watch.cancel()
        print(f"watch: {with_positions} frames with {n_vertices} vertex positions each")
        channel.close()
    finally:
        server.send_signal(signal.SIGTERM)
        try:
            code = server.wait(timeout=20)
        except subprocess.TimeoutExpired:
            server.kill()
            fail("the server did not exit within 20 s of SIGTERM")
    check(code == 0, f"server exit status {code}")
    print("any-language client: OK (server exited 0 on SIGTERM)")


if __name__ == "__main__":
    main()
