"""The VMC source against a third-party sender: the `vmcp` package (its osc4py3 backend, a
test-only dependency) sends a shared clip's humanoid bone and root transforms to a real
`streamkey run --from vmc://` over loopback. Every frame is received (or its drop counted),
and the keyframes are those of the same clip run from its file."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import humanoid_helpers
import pytest
from cmu import DATA
from live_helpers import MS, keyframes_of, read_jsonl, streamkey, wait_ready
from scipy.spatial.transform import Rotation

from streamkey.methods import ONLINE_METHODS
from streamkey.motion import Motion

try:
    from vmcp.osc import OSC
    from vmcp.osc.backend.osc4py3 import as_eventloop
    from vmcp.osc.typing import Message
    from vmcp.protocol import bone_transform, root_transform
    from vmcp.protocol import time as frame_time
    from vmcp.typing import Bone, CoordinateVector, Quaternion
except ImportError:
    if os.environ.get("CI") == "true":
        raise
    pytest.skip("vmcp is not installed (pip install vmcp osc4py3: the test extra)",
                allow_module_level=True)

# osc4py3 leaves its UDP sockets to the garbage collector at terminate (ResourceWarnings
# there); the only sockets of this process are the sender's, the run is another process.
pytestmark = pytest.mark.filterwarnings(
    r"ignore:Exception ignored in. <socket.socket:pytest.PytestUnraisableExceptionWarning")

CLIP = "07_05"
RATE = 240.0  # frames per second the sender keeps to at most


@pytest.fixture(scope="module")
def humanoid_clip(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Motion]:
    """The clip's motion on the built-in humanoid skeleton (metres), written and read back."""
    return humanoid_helpers.humanoid_clip(DATA / f"{CLIP}.bvh", tmp_path_factory.mktemp("vmcp"))


def vmcp_frames(motion: Motion) -> list[list[Any]]:
    """Each frame as vmcp messages: the root, every bone (local transform in Unity's axes:
    BVH -> Unity is the mirror x -> -x, quaternion (qx, -qy, -qz, qw)) and the frame time."""
    skel = motion.skeleton
    assert skel.rotation_order is not None
    bones = [Bone(name) for name in skel.names]  # vmcp knows every humanoid bone name
    out = []
    for i, row in enumerate(motion.channels):
        frame = [Message(*root_transform(CoordinateVector(0.0, 0.0, 0.0),
                                         Quaternion(0.0, 0.0, 0.0, 1.0)))]
        for j, bone in enumerate(bones):
            order = skel.rotation_order[j]
            cols = [skel.channel_index(j, c) for c in order]
            qx, qy, qz, qw = Rotation.from_euler("".join(c[0] for c in order), row[cols],
                                                 degrees=True).as_quat()
            x, y, z = skel.offsets[j] + (row[:3] if j == 0 else 0.0)
            frame.append(Message(*bone_transform(bone, CoordinateVector(-x, y, z),
                                                 Quaternion(qx, -qy, -qz, qw))))
        frame.append(Message(*frame_time(i / motion.fps)))
        out.append(frame)
    return out


def send_with_vmcp(port: int, frames: list[list[Any]], run: subprocess.Popen[str]) -> None:
    """vmcp sends one OSC bundle per frame, never faster than RATE frames a second; stops
    early if the run has ended."""
    with OSC(as_eventloop) as osc:
        sender = osc.create_sender("127.0.0.1", port, "streamkey").open()
        t0 = time.monotonic()
        for i, frame in enumerate(frames):
            # the rate bound of a capture device (pacing, not waiting for any state)
            time.sleep(max(0.0, t0 + i / RATE - time.monotonic()))
            if run.poll() is not None:
                break
            sender.send(frame)
            osc.run()
        osc.run()
        sender.close()


def _summary_number(err: str, pattern: str) -> int:
    """The integer `pattern`'s group captures in the run's summary on stderr."""
    found = re.search(pattern, err)
    assert found, f"{pattern!r} not in the summary: {err[-2000:]}"
    return int(found.group(1))


def test_vmcp_sender_feeds_a_real_run_that_keys_as_the_file_does(
        tmp_path: Path, humanoid_clip: tuple[Path, Motion]) -> None:
    """A real `streamkey run --from vmc://127.0.0.1:0` fed by vmcp: every one of the clip's
    frames arrives (none dropped, every drop would be counted), and every online method's
    keyframes equal those of the run from the file (vmcp sends float32, as VMC does)."""
    path, motion = humanoid_clip
    direct, live = tmp_path / "direct.jsonl", tmp_path / "vmcp.jsonl"
    ref = subprocess.run([sys.executable, "-m", "streamkey", "run", "--from", str(path),
                          "--fast", "--to", f"jsonl:{direct}"], capture_output=True, text=True,
                         timeout=600 * MS)
    assert ref.returncode == 0, ref.stderr
    frames = vmcp_frames(motion)
    run = streamkey("run", "--from", "vmc://127.0.0.1:0", "--skeleton", str(path),
                    "--to", f"jsonl:{live}", "--idle-exit", str(2.0 * MS))
    try:
        port = int(wait_ready(run, timeout=600.0)[-1].rsplit(":", 1)[1])
        send_with_vmcp(port, frames, run)
        _, err = run.communicate(timeout=600 * MS)  # the run stops itself when idle
    finally:
        if run.poll() is None:
            run.kill()
            run.communicate()
    assert run.returncode == 0, err
    sent = len(frames)
    assert sent == motion.n_frames
    # every datagram that arrived is accounted for: processed, or dropped and counted
    assert _summary_number(err, r"accounting: (\d+) frames or packets arrived") == sent, err
    assert _summary_number(err, r"(\d+) processed;") == sent, err
    assert _summary_number(err, r"frames in: (\d+)") == sent, err
    assert _summary_number(err, r"kernel receive drops: (\d+)") == 0, err
    assert _summary_number(err, r"malformed: (\d+)") == 0, err
    got, want = keyframes_of(read_jsonl(live)), keyframes_of(read_jsonl(direct))
    assert {m for m, _, _ in want} == set(ONLINE_METHODS)
    assert got == want
