"""A stand-in for Axis Neuron's "BVH data broadcasting" TCP server, written from Noitom's
description (Axis Neuron User Guide, "Broadcasting > BVH"; NeuronDataReader `DataType.h`
`_BvhDataHeader`): frames of a BVH clip as String (`<index> <name> values ||`) or Binary
(64-byte header 0xDDFF ... 0xEEFF, then float32 values).

Prints `listening PORT` once the server socket is up, serves one client at a time, paces
writes at --rate chunks per second, and exits after the last frame.
"""

from __future__ import annotations

import argparse
import random
import socket
import struct
import sys
import time

import numpy as np

from streamkey.bvh import read_bvh


def frame_values(skel, row: np.ndarray, disp: bool, ref: bool) -> np.ndarray:  # noqa: ANN001
    """The values Axis sends for one frame: optional reference bone, then every joint."""
    out: list[float] = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0] if ref else []
    for j, chans in enumerate(skel.channels):
        values = list(row[skel.channel_start[j]: skel.channel_start[j] + len(chans)])
        if disp and len(chans) == 3:
            values = list(skel.offsets[j]) + values  # every joint gets its displacement
        out += values
    return np.array(out)


def encode(fmt: str, avatar: int, seq: int, values: np.ndarray, disp: bool, ref: bool) -> bytes:
    name = f"Avatar{avatar:02d}"
    if fmt == "text":
        return (f"{avatar} {name} " + " ".join(repr(float(v)) for v in values) + " ||\n").encode()
    header = struct.pack("<HIHBBI32sIIIIH", 0xDDFF, 0x01000002, len(values), disp, ref,
                         avatar, name.encode(), seq, 0, 0, 0, 0xEEFF)
    return header + values.astype("<f4").tobytes()


def serve(listener: socket.socket, data: bytes, cuts: list[int], rate: float) -> None:
    conn, _ = listener.accept()
    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    t0 = time.monotonic()
    for i, (lo, hi) in enumerate(zip(cuts[:-1], cuts[1:], strict=True)):
        delay = t0 + i / rate - time.monotonic()
        if delay > 0:
            time.sleep(delay)  # pacing like a capture system, not waiting for the reader
        conn.sendall(data[lo:hi])
    conn.close()


def listen(port: int) -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.bind(("127.0.0.1", port))
    s.listen(1)
    return s


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("clip")
    p.add_argument("--format", choices=("text", "binary"), default="text")
    p.add_argument("--disp", action="store_true")
    p.add_argument("--ref", action="store_true")
    p.add_argument("--rate", type=float, default=240.0, help="writes per second")
    p.add_argument("--restart-after", type=int, default=0,
                   help="close everything after N frames, then listen again on the same port")
    p.add_argument("--other-avatar", action="store_true", help="interleave avatar 1 frames")
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args()
    motion = read_bvh(args.clip)
    rng = random.Random(args.seed)
    frames = []
    for seq in range(motion.first_frame, motion.n_frames):
        values = frame_values(motion.skeleton, motion.channels[seq], args.disp, args.ref)
        frames.append(encode(args.format, 0, seq, values, args.disp, args.ref))
        if args.other_avatar and seq % 7 == 0:
            frames.append(encode(args.format, 1, seq, values * 0.5, args.disp, args.ref))
    parts = [frames[: args.restart_after], frames[args.restart_after:]] if (
        args.restart_after) else [frames]
    listener = listen(0)
    port = listener.getsockname()[1]
    print(f"listening {port}", flush=True)
    for k, part in enumerate(parts):
        data = b"".join(part)
        mean = len(data) / len(part)
        # The first write holds two whole frames; then random chunks: some end mid-frame
        # (partial reads), some hold two frames.
        cuts = [0, len(part[0]) + len(part[1])]
        while cuts[-1] < len(data):
            cuts.append(min(len(data), cuts[-1] + int(rng.uniform(0.3, 1.7) * mean) + 1))
        serve(listener, data, cuts, args.rate)
        if k + 1 < len(parts):
            listener.close()
            listener = listen(port)  # the server comes back on the same port
    listener.close()
    print("done", flush=True)


if __name__ == "__main__":
    sys.exit(main())
