"""Strict ASF/AMC reader (CMU's native Acclaim format) onto the streamkey motion model.

The ASF skeleton becomes a `Skeleton` with one joint per bone plus `root`; a joint's position is
its bone's START, as in BVH, so joint b's offset is its parent bone's `direction * length` (zero
for the bones hanging from the root) and leaf bones get an end site at `direction * length`.
Lengths stay in the file's unit (the CMU `length 0.45` unit, the unit of the cgspeed BVH files).

Rotations follow the Acclaim convention used by CMU's mocapPlayer: a bone with `dof rx ry rz`
rotates by M = Rz·Ry·Rx (the reverse of the dof order), its `axis a b c XYZ` gives
C = Rz(c)·Ry(b)·Rx(a), and its local rotation in the world-aligned rest frame is C·M·Cᵀ. So
`rotation_order[j]` is the reversed dof order and `pre_rotations[j]` is C. Channel columns
within a joint follow the AMC value order (the ASF dof order). Every defect raises one
`AMCError` naming the file, the line and what was expected.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import numpy as np

from . import inputs
from .errors import AMCError, InputError, UsageError
from .kinematics import euler_matrices, skeleton_defect
from .motion import Motion, Skeleton

__all__ = ["read_asf", "parse_asf", "read_amc", "parse_amc", "read_motion", "bvh_equivalent"]

_DOF = {"rx": "Xrotation", "ry": "Yrotation", "rz": "Zrotation"}
_ROOT_ORDER = {"TX": "Xposition", "TY": "Yposition", "TZ": "Zposition",
               "RX": "Xrotation", "RY": "Yrotation", "RZ": "Zrotation"}
_AXIS_LETTER = {"X": "Xrotation", "Y": "Yrotation", "Z": "Zrotation"}


@dataclass
class _Bone:
    name: str
    line: int
    direction: np.ndarray | None = None
    length: float | None = None
    axis: np.ndarray | None = None  # C, 3x3
    dof: list[str] = field(default_factory=list)


@dataclass
class _Asf:
    source: str
    angle_scale: float = 1.0  # multiply file angles by this to get degrees
    root_order: list[str] = field(default_factory=lambda: list(_ROOT_ORDER.values()))
    root_axis: str = "XYZ"
    root_orientation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    bones: dict[str, _Bone] = field(default_factory=dict)
    children: dict[str, list[str]] | None = None
    seen: set[str] = field(default_factory=set)


def _err(source: str, line: int, msg: str) -> AMCError:
    return AMCError(f"{source}:{line}: {msg}")


def _numbers(words: list[str], count: int, source: str, line: int, what: str) -> list[float]:
    if len(words) != count:
        raise _err(source, line, f"expected {count} numbers for {what}, got {len(words)}")
    out = []
    for w in words:
        v = inputs.parse_number(w)
        if v is None:
            raise _err(source, line, f"expected a number for {what}, got {w!r}")
        if abs(v) > inputs.VALUE_LIMIT:
            raise _err(source, line, f"expected a number within +-{inputs.VALUE_LIMIT:g}"
                       f" for {what}, got {w!r}")
        out.append(v)
    return out


def _axis_matrix(angles: list[float], order: str, scale: float, source: str,
                 line: int) -> np.ndarray:
    """C from an ASF axis: order `XYZ` means C = Rz·Ry·Rx (mocapPlayer's convention)."""
    letters = order.upper()
    if sorted(letters) != ["X", "Y", "Z"]:
        raise _err(source, line, f"expected an axis order such as XYZ, got {order!r}")
    by_letter = dict(zip("XYZ", angles, strict=True))
    rev = letters[::-1]
    degrees = np.array([by_letter[c] * scale for c in rev])
    return euler_matrices(degrees, [_AXIS_LETTER[c] for c in rev])


def _sections(lines: list[str], source: str
              ) -> list[tuple[str, int, list[tuple[int, list[str]]]]]:
    """Split ASF lines into (keyword, line, [(line, words)]) sections; comments dropped."""
    out: list[tuple[str, int, list[tuple[int, list[str]]]]] = []
    for number, raw in enumerate(lines, start=1):
        words = raw.split("#", 1)[0].split()
        if not words:
            continue
        if words[0].startswith(":"):
            out.append((words[0].lower(), number, [(number, words[1:])] if words[1:] else []))
        elif out:
            out[-1][2].append((number, words))
        else:
            raise _err(source, number, f"expected an ASF keyword such as :version, got"
                       f" {words[0]!r}")
    return out


def _parse_units(asf: _Asf, body: list[tuple[int, list[str]]]) -> None:
    for line, words in body:
        if words[0] == "angle":
            unit = words[1].lower() if len(words) == 2 else ""
            if unit not in ("deg", "rad"):
                raise _err(asf.source, line, f"expected 'angle deg' or 'angle rad', got"
                           f" {' '.join(words)!r}")
            asf.angle_scale = 1.0 if unit == "deg" else 180.0 / math.pi
        elif words[0] in ("length", "mass"):
            _numbers(words[1:], 1, asf.source, line, f"the {words[0]} unit")


def _parse_root(asf: _Asf, body: list[tuple[int, list[str]]]) -> None:
    for line, words in body:
        key, rest = words[0].lower(), words[1:]
        if key == "order":
            bad = [w for w in rest if w.upper() not in _ROOT_ORDER]
            if bad or len(set(w.upper() for w in rest)) != len(rest):
                raise _err(asf.source, line, "expected a root order of distinct TX TY TZ RX RY RZ,"
                           f" got {' '.join(rest)!r}")
            asf.root_order = [_ROOT_ORDER[w.upper()] for w in rest]
        elif key == "axis":
            if len(rest) != 1 or sorted(rest[0].upper()) != ["X", "Y", "Z"]:
                raise _err(asf.source, line, f"expected a root axis such as XYZ, got {rest!r}")
            asf.root_axis = rest[0].upper()
        elif key == "position":
            # The AMC root translation is absolute (mocapPlayer overwrites the ASF position).
            _numbers(rest, 3, asf.source, line, "the root position")
        elif key == "orientation":
            asf.root_orientation = np.array(_numbers(rest, 3, asf.source, line,
                                                     "the root orientation"))
        else:
            raise _err(asf.source, line, f"expected order, axis, position or orientation in"
                       f" :root, got {words[0]!r}")


def _bone_field(asf: _Asf, bone: _Bone, line: int, words: list[str]) -> None:
    key, rest, src = words[0].lower(), words[1:], asf.source
    if key == "name":
        if len(rest) != 1:
            raise _err(src, line, f"expected one bone name, got {' '.join(rest)!r}")
        bone.name = rest[0]
    elif key == "direction":
        bone.direction = np.array(_numbers(rest, 3, src, line, "the bone direction"))
    elif key == "length":
        bone.length = _numbers(rest, 1, src, line, "the bone length")[0]
    elif key == "axis":
        if len(rest) != 4:
            raise _err(src, line, f"expected 'axis a b c XYZ', got {' '.join(words)!r}")
        angles = _numbers(rest[:3], 3, src, line, "the bone axis")
        bone.axis = _axis_matrix(angles, rest[3], asf.angle_scale, src, line)
    elif key == "dof":
        bad = [w for w in rest if w.lower() not in _DOF]
        if bad or not rest or len({w.lower() for w in rest}) != len(rest):
            raise _err(src, line, "expected distinct rotational dof rx, ry, rz (translation and"
                       f" length dof are not supported), got {' '.join(rest)!r}")
        bone.dof = [w.lower() for w in rest]
    elif key in ("id", "bodymass", "cofmass"):
        pass
    elif key != "limits" and not key.startswith("("):
        raise _err(src, line, f"expected a bone field (id, name, direction, length, axis, dof,"
                   f" limits), got {words[0]!r}")


def _finish_bone(asf: _Asf, bone: _Bone, line: int) -> None:
    src = asf.source
    if not bone.name:
        raise _err(src, line, "expected a 'name' in the bone ending here")
    for what, value in (("direction", bone.direction), ("length", bone.length),
                        ("axis", bone.axis)):
        if value is None:
            raise _err(src, line, f"expected a '{what}' in bone {bone.name!r}")
    if bone.name in asf.bones or bone.name == "root":
        raise _err(src, bone.line, f"expected a new bone name, got duplicate {bone.name!r}")
    asf.bones[bone.name] = bone


def _parse_bonedata(asf: _Asf, body: list[tuple[int, list[str]]]) -> None:
    bone: _Bone | None = None
    for line, words in body:
        key = words[0].lower()
        if key == "begin":
            if bone is not None:
                raise _err(asf.source, line, "expected 'end' before the next 'begin'")
            bone = _Bone("", line)
        elif key == "end":
            if bone is None:
                raise _err(asf.source, line, "expected 'begin' before 'end'")
            _finish_bone(asf, bone, line)
            bone = None
        elif bone is None:
            raise _err(asf.source, line, f"expected 'begin' of a bone, got {words[0]!r}")
        else:
            _bone_field(asf, bone, line, words)
    if bone is not None:
        raise _err(asf.source, body[-1][0], f"expected 'end' of bone {bone.name or '?'!r}")


def _parse_hierarchy(asf: _Asf, body: list[tuple[int, list[str]]]) -> None:
    children: dict[str, list[str]] = {}
    inside = False
    for line, words in body:
        if words[0].lower() in ("begin", "end") and len(words) == 1:
            inside = words[0].lower() == "begin"
            continue
        if not inside:
            raise _err(asf.source, line, f"expected 'begin' in :hierarchy, got {words[0]!r}")
        for name in words:
            if name != "root" and name not in asf.bones:
                raise _err(asf.source, line, f"expected a bone of :bonedata, got {name!r}")
        if len(words) < 2:
            raise _err(asf.source, line, f"expected a parent and its children, got {words!r}")
        children.setdefault(words[0], []).extend(words[1:])
    asf.children = children


def _build_skeleton(asf: _Asf, last_line: int) -> Skeleton:
    assert asf.children is not None
    names, parents = ["root"], [-1]
    stack = [(c, 0) for c in reversed(asf.children.get("root", []))]
    while stack:
        name, parent = stack.pop()
        if name in names:
            raise _err(asf.source, last_line, f"expected a tree in :hierarchy, {name!r} appears"
                       " twice")
        names.append(name)
        parents.append(parent)
        stack += [(c, len(names) - 1) for c in reversed(asf.children.get(name, []))]
    lost = [b for b in asf.bones if b not in names]
    if lost:
        raise _err(asf.source, last_line, f"expected every bone in :hierarchy under root,"
                   f" missing {', '.join(lost)}")
    bones = [asf.bones[n] for n in names[1:]]
    vectors = [np.zeros(3)] + [np.asarray(b.direction) * float(b.length or 0.0) for b in bones]
    offsets = np.array([vectors[p] if p >= 0 else np.zeros(3) for p in parents])
    channels = [list(asf.root_order)] + [[_DOF[d] for d in b.dof] for b in bones]
    order = [[c for c in ch if c.endswith("rotation")][::-1] for ch in channels]
    root_c = _axis_matrix(list(asf.root_orientation), asf.root_axis, asf.angle_scale,
                          asf.source, last_line)
    pre: list[np.ndarray | None] = [None if np.allclose(root_c, np.eye(3)) else root_c]
    # every bone has an axis (_finish_bone)
    pre += [b.axis if b.dof and not np.allclose(cast(np.ndarray, b.axis), np.eye(3)) else None
            for b in bones]
    ends = {j: vectors[j] for j in range(1, len(names)) if j not in parents}
    skeleton = Skeleton(names, parents, offsets, channels, ends, order, pre)
    defect = skeleton_defect(skeleton, inputs.VALUE_LIMIT)
    if defect:
        raise _err(asf.source, last_line, defect.replace("OFFSET", "bone direction x length"))
    return skeleton


def _parse_asf_full(text: str, source: str) -> tuple[Skeleton, float]:
    lines = text.removeprefix("\ufeff").splitlines()  # a byte-order mark some editors write
    asf = _Asf(source)
    sections = _sections(lines, source)
    handlers = {":units": _parse_units, ":root": _parse_root, ":bonedata": _parse_bonedata,
                ":hierarchy": _parse_hierarchy}
    for key, _line, body in sorted(sections, key=lambda s: list(handlers).index(s[0])
                                   if s[0] in handlers else -1):
        if key in handlers:
            if key in asf.seen:
                raise _err(source, _line, f"expected one {key} section, got a second")
            asf.seen.add(key)
            handlers[key](asf, body)
    end = max(len(lines), 1)
    for key in (":bonedata", ":hierarchy"):
        if key not in asf.seen:
            raise _err(source, end, f"expected a {key} section, found none")
    return _build_skeleton(asf, end), asf.angle_scale


def parse_asf(text: str, source: str = "<string>") -> Skeleton:
    """Parse ASF text into a `Skeleton` (joint = bone start); `source` names it in errors."""
    return _parse_asf_full(text, source)[0]


def _read_text(path: Path, kind: str) -> str:
    return inputs.read_text_file(path, kind, AMCError)


def read_asf(path: str | os.PathLike[str]) -> Skeleton:
    """Read an ASF skeleton file; raises `AMCError` naming the file and line on any defect."""
    p = Path(path)
    return parse_asf(_read_text(p, "ASF"), str(p))


class _AmcState:
    """Collects AMC frames: bone value strings by column, with their line numbers."""

    def __init__(self, skeleton: Skeleton, source: str) -> None:
        self.skel, self.source = skeleton, source
        self.cols = {n: (skeleton.channel_start[j], len(skeleton.channels[j]))
                     for j, n in enumerate(skeleton.names) if skeleton.channels[j]}
        self.rows: list[list[str]] = []
        self.lines: list[list[int]] = []
        self.seen: set[str] = set()
        self.number: int | None = None
        self.frame_line = 0

    def close_frame(self, line: int, what: str) -> None:
        if self.number is None:
            return
        missing = [n for n in self.cols if n not in self.seen]
        if missing:
            raise _err(self.source, line, f"expected values for bone(s) {', '.join(missing)} in"
                       f" frame {self.number} (line {self.frame_line}), got {what}")

    def start_frame(self, number: int, line: int) -> None:
        if self.number is not None and number != self.number + 1:
            raise _err(self.source, line, f"expected frame number {self.number + 1},"
                       f" got {number} (frames out of sequence)")
        self.number, self.frame_line, self.seen = number, line, set()
        self.rows.append([""] * self.skel.n_channels)
        self.lines.append([line] * self.skel.n_channels)

    def bone(self, words: list[str], line: int) -> None:
        name = words[0]
        if self.number is None:
            raise _err(self.source, line, f"expected a frame number, got {name!r}")
        if name not in self.cols:
            raise _err(self.source, line, f"expected a bone with dof of the skeleton, got"
                       f" {name!r}")
        if name in self.seen:
            raise _err(self.source, line, f"expected each bone once a frame, got {name!r} twice")
        start, count = self.cols[name]
        if len(words) - 1 != count:
            raise _err(self.source, line, f"expected {count} values for bone {name!r},"
                       f" got {len(words) - 1}")
        self.seen.add(name)
        self.rows[-1][start : start + count] = words[1:]
        self.lines[-1][start : start + count] = [line] * count


def _to_values(state: _AmcState) -> np.ndarray:
    flat = [w for row in state.rows for w in row]
    values = None
    if inputs.numbers_only(" ".join(flat)):
        try:
            values = np.array(flat, dtype=np.float64)
        except ValueError:
            pass
    if values is None:
        values = np.array([_float_or_nan(w) for w in flat])
    values = values.reshape(len(state.rows), state.skel.n_channels)
    bad = ~(np.abs(values) <= inputs.VALUE_LIMIT)
    if bad.any():
        i, col = np.argwhere(bad)[0]
        limit = f" within +-{inputs.VALUE_LIMIT:g}" if np.isfinite(values[i, col]) else ""
        raise _err(state.source, state.lines[i][col], f"expected a finite number{limit}, got"
                   f" {state.rows[i][col]!r}")
    return values


def _float_or_nan(word: str) -> float:
    value = inputs.parse_number(word)
    return math.nan if value is None else value


def parse_amc(text: str, skeleton: Skeleton, source: str = "<string>", *,
              angle_scale: float = 1.0) -> np.ndarray:
    """Parse AMC text into channel values (n_frames x skeleton.n_channels, degrees).

    `angle_scale` converts the file's angles to degrees when the AMC header does not say
    (`:DEGREES` / `:RADIANS`); `read_amc` passes the ASF's `angle` unit.
    """
    state = _AmcState(skeleton, source)
    lines = text.removeprefix("\ufeff").splitlines()  # a byte-order mark some editors write
    for number, raw in enumerate(lines, start=1):
        words = raw.split("#", 1)[0].split()
        if not words:
            continue
        if words[0].startswith(":"):
            if state.number is not None:
                raise _err(source, number, f"expected a frame, got header line {words[0]!r}")
            key = words[0].upper()
            angle_scale = {":DEGREES": 1.0, ":RADIANS": 180.0 / math.pi}.get(key, angle_scale)
        elif len(words) == 1 and inputs.parse_count(words[0]) is not None:
            state.close_frame(number, f"frame {words[0]}")
            state.start_frame(int(words[0]), number)
        else:
            state.bone(words, number)
    end = max(len(lines), 1)
    if state.number is None:
        raise _err(source, end, "expected at least one numbered frame, found none")
    state.close_frame(end, "end of file (truncated last frame)")
    values = _to_values(state)
    rot = skeleton.rotation_columns()
    if angle_scale != 1.0 and len(rot):
        values[:, rot] *= angle_scale
    return values


def read_amc(amc_path: str | os.PathLike[str], asf_path: str | os.PathLike[str] | None = None,
             fps: float = 120.0) -> Motion:
    """Read an AMC clip and its ASF skeleton (default `<subject>.asf` beside it) as a `Motion`.

    AMC files carry no frame rate: `fps` defaults to CMU's 120. There is no reference frame.
    """
    low, high = inputs.FRAME_TIME_RANGE
    if not (isinstance(fps, int | float) and 1 / high <= fps <= 1 / low):
        raise UsageError(f"fps must be a number in {1 / high:g}..{1 / low:g}, got {fps!r}")
    amc = Path(amc_path)
    if asf_path is None:
        asf = amc.with_name(amc.stem.split("_", 1)[0] + ".asf")
        if not asf.is_file() and amc.is_file():
            raise AMCError(f"{amc}: expected its skeleton {asf.name} beside it (CMU naming"
                           f" SS_TT.amc -> SS.asf), found none; give the ASF path")
    else:
        asf = Path(asf_path)
    text = _read_text(amc, "AMC")
    skeleton, scale = _parse_asf_full(_read_text(asf, "ASF"), str(asf))
    values = parse_amc(text, skeleton, str(amc), angle_scale=scale)
    return Motion(skeleton, values, float(fps), 0, amc.stem)


def read_motion(path: str | os.PathLike[str]) -> Motion:
    """Read a BVH (`.bvh`) or AMC (`.amc`, skeleton beside it) file by its suffix."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".bvh":
        from .bvh import read_bvh

        return read_bvh(p)
    if suffix == ".amc":
        return read_amc(p)
    raise InputError(f"{p}: expected a .bvh or .amc file, got suffix {p.suffix or '(none)'!r}")


def bvh_equivalent(motion: Motion) -> Motion:
    """The same motion on a plain BVH skeleton: no axis pre-rotations, channels in BVH order.

    A joint with a pre-rotation C gets three rotation channels (Z, Y, X, applied in that
    order) whose angles are the Euler decomposition of its local rotation C·M·Cᵀ, unwrapped
    over time; other joints keep their values, reordered so the rotation channels list the
    order in which they compose (BVH's rule). Names, offsets and end sites stay, so FK
    positions are equal to rounding (tested against the AMC reader). A motion that is
    already plain BVH is returned as is.
    """
    skel = motion.skeleton
    assert skel.rotation_order is not None and skel.pre_rotations is not None
    if skel.bvh_compatible():
        return motion
    from scipy.spatial.transform import Rotation

    from .kinematics import local_rotations

    local = local_rotations(skel, motion.channels) if motion.n_frames else None
    channels: list[list[str]] = []
    columns: list[np.ndarray] = []
    for j, (chans, order) in enumerate(zip(skel.channels, skel.rotation_order, strict=True)):
        start = skel.channel_start[j]
        positions = [c for c in chans if c not in order]
        columns += [motion.channels[:, start + chans.index(c)] for c in positions]
        if skel.pre_rotations[j] is None:
            channels.append(positions + list(order))
            columns += [motion.channels[:, start + chans.index(c)] for c in order]
            continue
        channels.append(positions + ["Zrotation", "Yrotation", "Xrotation"])
        if local is None:
            columns += [np.zeros(0)] * 3
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # gimbal lock: still exact
            angles = Rotation.from_matrix(local[:, j]).as_euler("ZYX", degrees=True)
        angles = np.unwrap(angles, period=360.0, axis=0)
        columns += [angles[:, 0], angles[:, 1], angles[:, 2]]
    values = np.stack(columns, axis=1) if columns else np.zeros((motion.n_frames, 0))
    plain_skel = Skeleton(list(skel.names), list(skel.parents), skel.offsets.copy(), channels,
                          dict(skel.end_sites))
    return Motion(plain_skel, values.reshape(motion.n_frames, plain_skel.n_channels), motion.fps,
                  motion.first_frame, motion.name)
