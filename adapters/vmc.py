"""VMC protocol in (`--from vmc://127.0.0.1:39539`): the OSC stream of XR Animator,
VirtualMotionCapture, Warudo, SlimeVR and other "Virtual Motion Capture" senders.

Messages used (VMC protocol specification, https://protocol.vmc.info/specification):

    /VMC/Ext/Root/Pos  s name, f px py pz, f qx qy qz qw     the avatar root (world)
    /VMC/Ext/Bone/Pos  s bone, f px py pz, f qx qy qz qw     one bone, local to its parent

Bone names are Unity `HumanBodyBones` names (`Hips`, `LeftUpperArm`, ...). A sender sends one
OSC bundle per frame: every bundle that holds a Root/Pos or Bone/Pos message ends a frame
(frames numbered from 0 as they arrive; `fps` from `--skeleton`, else 60). Bones keep their last
rotation until updated; bones the skeleton does not have (eyes, jaw, other fingers) and other
addresses (`/VMC/Ext/Blend/Val`, `/VMC/Ext/OK`, `/VMC/Ext/T`, ...) are ignored. Doubles (`d`)
are accepted wherever the specification says `f`.

Axis conversion. Unity is left-handed (X right, Y up, Z forward); the BVH skeleton is
right-handed with Y up, Z forward and the performer's left on +X. The change of basis is the
mirror M = diag(-1, 1, 1): a position (x, y, z) becomes (-x, y, z) and a rotation R becomes
M R M, i.e. the quaternion (qx, qy, qz, qw) becomes (qx, -qy, -qz, qw). The hips' world pose
is root * hips-local; its position, times `?scale=` (skeleton units per metre, default 1: the
built-in humanoid is in metres), fills the root position channels. Each bone's local rotation
becomes the joint's Euler channels with scipy `Rotation.as_euler` in the joint's own order
(intrinsic, as BVH composes them). The skeleton is `streamkey.rigs.humanoid_skeleton()` or
`--skeleton FILE` whose joints carry Unity bone names.

A datagram that is not OSC, or a Root/Pos / Bone/Pos message with the wrong argument types or
non-finite values, is dropped and counted (`parse`, `types`).
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np
from pythonosc.osc_bundle import OscBundle
from pythonosc.osc_message import OscMessage
from scipy.spatial.transform import Rotation

from streamkey.errors import UsageError
from streamkey.motion import POSITION_CHANNELS, Frame, Skeleton

from .base import MAX_MESSAGE_BYTES, Address, bind_host
from .udp_listen import DatagramSource

__all__ = ["VmcSource", "VmcDecoder", "ROOT_ADDRESS", "BONE_ADDRESS"]

ROOT_ADDRESS = "/VMC/Ext/Root/Pos"
BONE_ADDRESS = "/VMC/Ext/Bone/Pos"


class VmcDecoder:
    """VMC datagrams -> channel vectors of one skeleton (sans-I/O; raises ValueError)."""

    def __init__(self, skeleton: Skeleton, scale: float = 1.0) -> None:
        self.skeleton = skeleton
        self.scale = scale
        self.joints = {name: j for j, name in enumerate(skeleton.names)}
        self.rotations = np.tile([0.0, 0.0, 0.0, 1.0], (skeleton.n_joints, 1))  # BVH axes
        self.hips_position = skeleton.offsets[0] / scale  # metres, BVH axes: channels 0
        self.root = (np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))
        # joints grouped by Euler sequence: one scipy call per group and frame
        self.groups: dict[str, tuple[list[int], list[list[int | None]]]] = {}
        for j, order in enumerate(skeleton.rotation_order or []):
            if order:
                joints, cols = self.groups.setdefault("".join(c[0] for c in order), ([], []))
                joints.append(j)
                cols.append([skeleton.channel_index(j, c) for c in order])
        self.position_columns = [skeleton.channel_index(0, c) for c in POSITION_CHANNELS]

    def datagram(self, data: bytes) -> np.ndarray | None:
        """Apply one datagram; the frame's channels if it was a bundle with pose messages."""
        if len(data) > MAX_MESSAGE_BYTES:
            raise ValueError(f"packet of {len(data)} bytes, more than {MAX_MESSAGE_BYTES}")
        try:
            if OscBundle.dgram_is_bundle(data):
                messages = _flatten(OscBundle(data))
                bundled = True
            else:
                messages, bundled = [OscMessage(data)], False
        except Exception as exc:  # python-osc raises several types for garbage
            raise ValueError(f"not OSC: {exc}") from None
        pose = [m for m in messages if m.address in (ROOT_ADDRESS, BONE_ADDRESS)]
        updates = [_transform(m) for m in pose]  # validate all before applying any
        for message, (name, x, y, z, qx, qy, qz, qw) in zip(pose, updates, strict=True):
            # Unity -> BVH axes: the mirror x -> -x (module docstring)
            if message.address == ROOT_ADDRESS:
                self.root = (np.array([-x, y, z]), np.array([qx, -qy, -qz, qw]))
            elif (j := self.joints.get(name)) is not None:
                self.rotations[j] = (qx, -qy, -qz, qw)
                if j == 0:
                    self.hips_position = np.array([-x, y, z])
        return self.channels() if bundled and pose else None

    def channels(self) -> np.ndarray:
        """The current pose as the skeleton's channel vector."""
        out = np.zeros(self.skeleton.n_channels)
        root_pos, root_rot = self.root
        root = Rotation.from_quat(root_rot)
        world = root * Rotation.from_quat(self.rotations[0])
        hips = (root_pos + root.apply(self.hips_position)) * self.scale - self.skeleton.offsets[0]
        for col, value in zip(self.position_columns, hips, strict=True):
            if col is not None:
                out[col] = value
        quats = self.rotations.copy()
        quats[0] = world.as_quat()
        with warnings.catch_warnings():  # gimbal lock: any valid angle triple is right
            warnings.simplefilter("ignore", UserWarning)
            for seq, (joints, cols) in self.groups.items():
                out[np.array(cols)] = Rotation.from_quat(quats[joints]).as_euler(
                    seq.upper(), degrees=True)
        return out


def _flatten(bundle: OscBundle) -> list[OscMessage]:
    out: list[OscMessage] = []
    for i in range(bundle.num_contents):
        content = bundle.content(i)
        out += _flatten(content) if isinstance(content, OscBundle) else [content]
    return out


def _transform(message: OscMessage) -> tuple[Any, ...]:
    params = message.params
    if (len(params) < 8 or not isinstance(params[0], str)
            or not all(isinstance(v, float) and math.isfinite(v) for v in params[1:8])):
        raise TypeError(f"{message.address}: expected s name, f px py pz, f qx qy qz qw "
                        "(finite)")
    if sum(v * v for v in params[4:8]) < 1e-12:
        raise TypeError(f"{message.address} {params[0]}: zero quaternion")
    return tuple(params[:8])


class VmcSource(DatagramSource):
    """Frames from a VMC sender: an OSC listener on UDP (127.0.0.1 unless `--listen`)."""

    name = "vmc"

    def __init__(self, address: Address, listen: str | None = None,
                 skeleton: Skeleton | None = None, fps: float | None = None) -> None:
        if skeleton is None:
            from streamkey.rigs import humanoid_skeleton

            skeleton = humanoid_skeleton()
        super().__init__(address, skeleton, fps)
        self.host = bind_host(address, listen)
        try:
            scale = float(address.options.get("scale", 1.0))
        except ValueError:
            scale = float("nan")
        if not (math.isfinite(scale) and scale > 0):
            raise UsageError(f"{address}: scale must be a positive number (units per metre)")
        missing = [b for b in ("Hips",) if b not in skeleton.names]
        if missing:
            raise UsageError(f"{address}: the skeleton needs Unity bone names (Hips, Spine, "
                             f"LeftUpperLeg, ...); joints are: {', '.join(skeleton.names)}")
        self.decoder = VmcDecoder(skeleton, scale)
        self.seq = 0

    async def start(self) -> str:
        port = await self.listen(self.host, self.receive)
        return f"vmc://{self.host}:{port}"

    def receive(self, data: bytes) -> None:
        """Handle one datagram (on the event loop); never raises."""
        try:
            channels = self.decoder.datagram(data)
        except ValueError as exc:
            self.stats.reject("parse", f"vmc: {exc}")
            return
        except TypeError as exc:
            self.stats.reject("types", f"vmc: {exc}")
            return
        if channels is None:
            return
        assert self.fps is not None
        self.stats.received += 1
        self.frames.put(Frame(self.seq, self.seq / self.fps, channels))
        self.seq += 1
