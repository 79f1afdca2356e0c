"""VMC source: axis conversion, BVH clip -> VMC bundles -> channels round trip, run fed by
VMC over UDP equals run from the file, fuzzed datagrams, hostile traffic counted by kind with
nothing printed per packet (bogus bundle element sizes, truncated bundles, odd type tags)."""

from __future__ import annotations

import logging
import random
import socket
import struct
import subprocess
import sys
import time
from collections import Counter

import humanoid_helpers
import numpy as np
import pytest
from cmu import DATA
from live_helpers import MS, keyframes_of, read_jsonl, streamkey, wait_ready
from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
from pythonosc.osc_message_builder import OscMessageBuilder
from scipy.spatial.transform import Rotation

from streamkey.adapters.base import parse_address
from streamkey.adapters.vmc import REQUIRED_BONES, VmcDecoder, VmcSource
from streamkey.methods import ONLINE_METHODS
from streamkey.motion import Motion
from streamkey.rigs import humanoid_skeleton

CLIP = DATA / "07_01.bvh"
@pytest.fixture(scope="module")
def humanoid_clip(tmp_path_factory) -> tuple:
    """07_01's motion on the built-in humanoid skeleton (metres), written and read back."""
    path, motion = humanoid_helpers.humanoid_clip(CLIP, tmp_path_factory.mktemp("vmc"))
    assert motion.first_frame == 0
    return path, motion


def _message(address: str, name: str, values, kind: str) -> bytes:  # type: ignore[no-untyped-def]
    m = OscMessageBuilder(address)
    m.add_arg(name, "s")
    for v in values:
        m.add_arg(float(v), kind)
    return m.build()


def vmc_bundles(motion: Motion, kind: str = "f") -> list[bytes]:
    """What a VMC sender transmits for each frame, from the documented conversion run
    backwards: BVH axes -> Unity axes is the same mirror (x -> -x; qx, -qy, -qz, qw)."""
    skel = motion.skeleton
    out = []
    for row in motion.channels:
        b = OscBundleBuilder(IMMEDIATELY)
        b.add_content(_message("/VMC/Ext/Root/Pos", "root", [0, 0, 0, 0, 0, 0, 1], kind))
        for j, name in enumerate(skel.names):
            order = skel.rotation_order[j]
            cols = [skel.channel_index(j, c) for c in order]
            quat = Rotation.from_euler("".join(c[0] for c in order), row[cols],
                                       degrees=True).as_quat() * [1, -1, -1, 1]
            pos = skel.offsets[j] + (row[:3] if j == 0 else 0)
            b.add_content(_message("/VMC/Ext/Bone/Pos", name, [*(pos * [-1, 1, 1]), *quat],
                                   kind))
        b.add_content(_message("/VMC/Ext/T", "t", [0.0], kind))
        out.append(b.build().dgram)
    return out


def test_unity_axes_map_to_the_performer_frame():
    decoder = VmcDecoder(humanoid_skeleton())
    # Unity: +90 deg about +Y turns forward (+Z) to the performer's right (+X in Unity).
    turn = Rotation.from_euler("y", 90, degrees=True).as_quat()
    b = OscBundleBuilder(IMMEDIATELY)
    b.add_content(_message("/VMC/Ext/Bone/Pos", "Hips", [1.0, 0.9, 0.0, *turn], "f"))
    for bone in sorted(REQUIRED_BONES - {"Hips"}):  # a frame carries every required bone
        b.add_content(_message("/VMC/Ext/Bone/Pos", bone, [0, 0, 0, 0, 0, 0, 1], "f"))
    channels = decoder.datagram(b.build().dgram)
    skel = decoder.skeleton
    cols = [skel.channel_index(0, c) for c in skel.rotation_order[0]]
    rot = Rotation.from_euler("ZYX", channels[cols], degrees=True)
    # BVH axes: the performer's left is +X, so their right is -X; position x mirrors too.
    assert np.allclose(rot.apply([0, 0, 1]), [-1, 0, 0], atol=1e-6)
    assert np.allclose(channels[:3], [-1.0, 0.9, 0.0], atol=1e-6)


def _unwrapped_error(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs((a - b + 180.0) % 360.0 - 180.0)))


@pytest.mark.parametrize("kind, tol", [("d", 1e-6), ("f", 1e-4)], ids=["double", "float32"])
def test_round_trip_clip_to_vmc_to_channels(humanoid_clip, kind, tol):
    _, motion = humanoid_clip
    decoder = VmcDecoder(motion.skeleton)
    got = np.array([decoder.datagram(d) for d in vmc_bundles(motion, kind)])
    rot = motion.skeleton.rotation_columns()
    assert _unwrapped_error(got[:, rot], motion.channels[:, rot]) < tol
    assert np.allclose(got[:, :3], motion.channels[:, :3], atol=1e-5 if kind == "f" else 1e-9)


def test_run_fed_by_vmc_equals_run_from_the_file(tmp_path, humanoid_clip):
    path, motion = humanoid_clip
    direct, live = tmp_path / "direct.jsonl", tmp_path / "vmc.jsonl"
    ref = subprocess.run([sys.executable, "-m", "streamkey", "run", "--from", str(path),
                          "--fast", "--to", f"jsonl:{direct}"], capture_output=True, text=True,
                         timeout=120 * MS)
    assert ref.returncode == 0, ref.stderr
    run = streamkey("run", "--from", "vmc://127.0.0.1:0", "--skeleton", str(path),
                    "--to", f"jsonl:{live}", "--idle-exit", str(1.5 * MS))
    try:
        port = int(wait_ready(run)[-1].rsplit(":", 1)[1])
        bundles = vmc_bundles(motion)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            t0 = time.monotonic()
            for i, data in enumerate(bundles):  # paced like a 120 Hz sender
                time.sleep(max(0.0, t0 + i / motion.fps - time.monotonic()))
                sock.sendto(data, ("127.0.0.1", port))
        _, err = run.communicate(timeout=120 * MS)
    finally:
        if run.poll() is None:
            run.kill()
            run.communicate()
    assert run.returncode == 0, err
    assert f"frames in: {motion.n_frames}" in err and "0 queue" in err
    got, want = keyframes_of(read_jsonl(live)), keyframes_of(read_jsonl(direct))
    assert got == want and {m for m, _, _ in want} == set(ONLINE_METHODS)


def test_fuzzed_vmc_datagrams_are_counted_never_raised(humanoid_clip, capfd):
    _, motion = humanoid_clip
    source = VmcSource(parse_address("vmc://127.0.0.1:0"), skeleton=motion.skeleton, fps=120.0)
    good = vmc_bundles(Motion(motion.skeleton, motion.channels[:40], motion.fps))
    rng = random.Random(9)
    bad = [_message("/VMC/Ext/Bone/Pos", "Hips", [1, 2, 3, float("nan"), 0, 0, 1], "f"),
           OscMessageBuilder("/VMC/Ext/Bone/Pos").build().dgram, b"", b"#bundle\0" + bytes(9)]
    for data in good:
        mutated = bytearray(data)
        for _ in range(rng.randrange(1, 6)):
            mutated[rng.randrange(len(mutated))] = rng.randrange(256)
        bad.append(bytes(mutated))
        bad.append(data[: rng.randrange(len(data))])
        bad.append(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 300))))
    for data in bad:
        source.receive(data)
    dropped = sum(source.stats.malformed.values())
    assert dropped >= 80 and dropped + source.stats.received <= len(bad)
    before = source.stats.received
    for data in good:
        source.receive(data)
    assert source.stats.received == before + len(good)
    assert capfd.readouterr() == ("", "")  # nothing printed per packet


@pytest.mark.skipif(sys.platform != "linux", reason="/proc/net/udp is Linux's")
def test_kernel_receive_buffer_drops_are_counted_for_the_vmc_listener():
    """A flood the loop never reads overflows the socket; the kernel's count reaches the
    source's counters (not 'not counted')."""
    import asyncio

    async def main() -> int | None:
        source = VmcSource(parse_address("vmc://127.0.0.1:0"))
        ready = await source.start()
        port = int(ready.rsplit(":", 1)[1])
        sock = source.transport.get_extra_info("socket")
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            for _ in range(2000):  # sent without yielding: nothing reads in between
                tx.sendto(b"x" * 512, ("127.0.0.1", port))
        drops = source.counters().kernel_drops
        await source.close()
        return drops

    drops = asyncio.run(main())
    assert drops is not None and drops > 0


def hostile_vmc(frame: bytes) -> list[tuple[bytes, str]]:
    """Packets a fuzzer found wrongly handled, each with the counter it must land in, made
    from one good frame bundle (the root, every bone, then /VMC/Ext/T)."""
    head, elements, at = frame[:16], [], 16
    while at < len(frame):
        (size,) = struct.unpack_from(">i", frame, at)
        elements.append(frame[at + 4: at + 4 + size])
        at += 4 + size

    def bundle(*parts: bytes) -> bytes:
        return head + b"".join(struct.pack(">i", len(p)) + p for p in parts)

    bone = elements[1]
    tags = bone.index(b",sfffffff")
    out = []
    for size in (0, 3, 6, -8, -len(bone), len(bone) + 4, 1 << 20):  # bogus element sizes
        out.append((head + struct.pack(">i", size) + bone, "bundle"))
    out.append((bundle(bone)[:-2], "bundle"))  # the last element cut inside
    # truncated at an element boundary: well-formed, but without the last bones
    out += [(bundle(*elements[:k]), "incomplete") for k in range(1, len(elements) - 1)]
    for odd in (b",sfffffffX", b",sffffffX", b",sffffffi", b",ssffffff", b",sfff\0\0\0\0\0\0"):
        out.append((bundle(bone[:tags] + odd + bone[tags + len(odd):]), "types"))
    out.append((bundle(bone + bytes(4)), "types"))  # more bytes than its type tags say
    out.append((bundle(bone[:tags] + b",s\0\0"), "types"))  # no values at all
    out.append((bundle(bytes(4)), "parse"))  # an element that is neither message nor bundle
    out.append((bundle(b"VMC\0" + bone[4:]), "parse"))
    out.append((bundle(b"/VMC/Ext/Bone/Pos..."), "parse"))  # an address without its NUL
    return out


def test_hostile_vmc_packets_are_counted_by_kind_and_print_nothing(humanoid_clip, capfd):
    _, motion = humanoid_clip
    source = VmcSource(parse_address("vmc://127.0.0.1:0"), skeleton=motion.skeleton, fps=120.0)
    good = vmc_bundles(Motion(motion.skeleton, motion.channels[:3], motion.fps))
    hostile = hostile_vmc(good[0])
    handlers = list(logging.root.handlers)
    source.receive(good[0])
    for data, _ in hostile * 5:
        source.receive(data)
    for data in good[1:]:
        source.receive(data)
    want = Counter(kind for _, kind in hostile * 5)
    assert source.stats.malformed == want, source.stats.last_error
    assert source.stats.received == len(good)
    assert want["incomplete"] == 5 * (len(motion.skeleton.names) + 1 - 1)
    out, err = capfd.readouterr()
    assert out == err == "" and logging.root.handlers == handlers


def test_a_bundle_without_the_required_bones_is_no_first_frame():
    decoder = VmcDecoder(humanoid_skeleton())
    b = OscBundleBuilder(IMMEDIATELY)
    b.add_content(_message("/VMC/Ext/Root/Pos", "root", [0, 0, 0, 0, 0, 0, 1], "f"))
    b.add_content(_message("/VMC/Ext/Bone/Pos", "Hips", [0, 0.9, 0, 0, 0, 0, 1], "f"))
    with pytest.raises(Exception, match="without 14 of the bones .*LeftFoot") as caught:
        decoder.datagram(b.build().dgram)
    assert getattr(caught.value, "kind", None) == "incomplete"


def test_hostile_vmc_traffic_over_loopback_is_counted_in_the_run_summary(tmp_path,
                                                                         humanoid_clip):
    """A real run fed over UDP: good frames with hostile packets between them; the summary
    counts every hostile packet by kind, nothing is printed per packet (python-osc printed
    one warning line per odd element), and every good frame arrives."""
    path, motion = humanoid_clip
    good = vmc_bundles(Motion(motion.skeleton, motion.channels[:240], motion.fps))
    hostile = hostile_vmc(good[0]) * 4
    assert len(hostile) < len(good)
    run = streamkey("run", "--from", "vmc://127.0.0.1:0", "--skeleton", str(path),
                    "--method", "speed", "--to", f"jsonl:{tmp_path / 'events.jsonl'}",
                    "--idle-exit", str(1.5 * MS))
    try:
        port = int(wait_ready(run, timeout=240)[-1].rsplit(":", 1)[1])
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            t0 = time.monotonic()
            for i, data in enumerate(good):
                time.sleep(max(0.0, t0 + i / motion.fps - time.monotonic()))
                sock.sendto(data, ("127.0.0.1", port))
                if i < len(hostile):
                    sock.sendto(hostile[i][0], ("127.0.0.1", port))
        _, err = run.communicate(timeout=120 * MS)
    finally:
        if run.poll() is None:
            run.kill()
            run.communicate()
    assert run.returncode == 0, err
    assert "Traceback" not in err and "WARNING" not in err and "dgram" not in err, err
    assert len(err.splitlines()) < 40, err  # a few explanations, not one line per packet
    assert f"frames in: {len(good)} " in err, err
    want = Counter(kind for _, kind in hostile)
    text = ", ".join(f"{k} {v}" for k, v in sorted(want.items()))
    assert f"malformed: {len(hostile)} ({text})" in err, err
