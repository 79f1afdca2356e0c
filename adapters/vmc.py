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

Every datagram that does not become a frame or a state update is dropped and counted by kind
(nothing is printed per packet): `oversize`; `bundle` (an element size that is not a positive
multiple of 4 inside the packet, bundles nested too deep); `parse` (not an OSC message or
bundle); `types` (a Root/Pos / Bone/Pos message whose type tags are not `s` then 7 or more
`f`/`d`, whose size does not match its tags, with non-finite values or a zero quaternion);
`incomplete` (a frame bundle that lacks a bone the frame needs: a truncated bundle). The
packets are decoded here, not by python-osc, whose parser logs a warning on stderr for every
odd element or type tag it skips, and skips them uncounted.

A frame bundle needs every bone that Unity's humanoid requires (Hips, Spine, Head, upper and
lower legs and arms, feet, hands) that the skeleton has, and every skeleton bone (and the root)
that the sender put in an earlier accepted frame: a performer sends all its bones in each frame,
so a bundle without some of them was cut short. Bones the avatar lacks (no UpperChest, no
fingers) are never asked for.
"""

from __future__ import annotations

import math
import re
import struct
import warnings

import numpy as np
from scipy.spatial.transform import Rotation

from streamkey.errors import UsageError
from streamkey.motion import POSITION_CHANNELS, Frame, Skeleton

from .base import MAX_MESSAGE_BYTES, Address, bind_host
from .osc import OscDecodeError, decode_bundle
from .udp_listen import DatagramSource

__all__ = ["VmcSource", "VmcDecoder", "ROOT_ADDRESS", "BONE_ADDRESS", "REQUIRED_BONES"]

ROOT_ADDRESS = "/VMC/Ext/Root/Pos"
BONE_ADDRESS = "/VMC/Ext/Bone/Pos"
# Unity's required HumanBodyBones: an avatar has them all, so a frame always carries them
REQUIRED_BONES = frozenset({"Hips", "Spine", "Head"} | {
    f"{side}{bone}" for side in ("Left", "Right")
    for bone in ("UpperLeg", "LowerLeg", "Foot", "UpperArm", "LowerArm", "Hand")})
MAX_BUNDLE_DEPTH = 8
_ROOT = "/root"  # the root's entry in the set of what a frame carries (never a bone name)
_POSE_TAGS = re.compile(r",s[fd]{7,}")

Pose = tuple[str, str, tuple[float, ...]]  # address, bone name, px py pz qx qy qz qw


class VmcDecoder:
    """VMC datagrams -> channel vectors of one skeleton (sans-I/O; raises `OscDecodeError`,
    whose `kind` names the counter)."""

    def __init__(self, skeleton: Skeleton, scale: float = 1.0) -> None:
        self.skeleton = skeleton
        self.scale = scale
        self.joints = {name: j for j, name in enumerate(skeleton.names)}
        self.rotations = np.tile([0.0, 0.0, 0.0, 1.0], (skeleton.n_joints, 1))  # BVH axes
        self.hips_position = skeleton.offsets[0] / scale  # metres, BVH axes: channels 0
        self.root = (np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))
        # what a frame bundle must carry: the required bones, then all the sender has sent
        self.expected = {name for name in skeleton.names if name in REQUIRED_BONES}
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
            raise OscDecodeError("oversize", f"packet of {len(data)} bytes, more than "
                                 f"{MAX_MESSAGE_BYTES}")
        bundled = data.startswith(b"#bundle\0")
        pose = _poses(data, 0)  # validate all before applying any
        if bundled and pose:
            carried = {name for address, name, _ in pose
                       if address == BONE_ADDRESS and name in self.joints}
            carried |= {_ROOT} if any(a == ROOT_ADDRESS for a, _, _ in pose) else set()
            missing = self.expected - carried
            if missing:
                names = ", ".join(sorted(m for m in missing if m != _ROOT)[:4]) or "the root"
                more = ", ..." if len(missing) > 4 else ""
                raise OscDecodeError("incomplete", f"a frame bundle without {len(missing)} of "
                                     f"the bones every frame carries ({names}{more}): cut short")
            self.expected |= carried
        for address, name, (x, y, z, qx, qy, qz, qw) in pose:
            # Unity -> BVH axes: the mirror x -> -x (module docstring)
            if address == ROOT_ADDRESS:
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


def _poses(data: bytes, depth: int) -> list[Pose]:
    """The Root/Pos and Bone/Pos messages of a datagram or bundle element, in order; other
    messages are skipped unread."""
    if data.startswith(b"#bundle\0"):
        if depth >= MAX_BUNDLE_DEPTH:
            raise OscDecodeError("bundle", f"bundles nested deeper than {MAX_BUNDLE_DEPTH}")
        return [p for element in decode_bundle(data)[1] for p in _poses(element, depth + 1)]
    if not data.startswith(b"/"):
        raise OscDecodeError("parse", "not OSC: neither a message (/address) nor a #bundle")
    address, at = _string(data, 0, "parse", "address")
    if address not in (ROOT_ADDRESS, BONE_ADDRESS):
        return []
    expected = "expected s name, f px py pz, f qx qy qz qw"
    tags, at = _string(data, at, "types", f"{address}: type tags")
    if not _POSE_TAGS.fullmatch(tags):
        raise OscDecodeError("types", f"{address}: type tags {tags[:40]!r}; {expected}")
    name, at = _string(data, at, "types", f"{address}: bone name")
    values = tags[2:]
    if len(data) - at != struct.calcsize(">" + values):
        raise OscDecodeError("types", f"{address} {name[:40]}: {len(data) - at} bytes of "
                             f"values for type tags {tags[:40]!r}")
    numbers = struct.unpack_from(">" + values, data, at)[:7]
    if not all(math.isfinite(v) for v in numbers):
        raise OscDecodeError("types", f"{address} {name[:40]}: non-finite value; {expected}")
    if sum(v * v for v in numbers[3:]) < 1e-12:
        raise OscDecodeError("types", f"{address} {name[:40]}: zero quaternion")
    return [(address, name, numbers)]


def _string(data: bytes, at: int, kind: str, what: str) -> tuple[str, int]:
    """The OSC string at `at` (NUL-terminated, padded to 4 bytes) and the offset after it."""
    end = data.find(b"\0", at)
    after = (end // 4 + 1) * 4
    if end < 0 or after > len(data) or data[end:after].strip(b"\0"):
        raise OscDecodeError(kind, f"{what}: not a NUL-padded OSC string at byte {at}")
    return data[at:end].decode("utf-8", "replace"), after


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
        except OscDecodeError as exc:
            self.stats.reject(exc.kind, f"vmc: {exc}")
            return
        except Exception as exc:  # a decoder bug: counted, the source goes on
            self.stats.reject("internal", f"vmc: {type(exc).__name__}: {str(exc)[:200]}")
            return
        if channels is None:
            return
        assert self.fps is not None
        self.stats.received += 1
        self.frames.put(Frame(self.seq, self.seq / self.fps, channels))
        self.seq += 1
