"""Strict, fast BVH reader and writer.

Accepts the usual variants (any rotation order, end sites, CRLF, tabs or spaces, `Frame Time`
with or without a leading zero). Every defect raises one `BVHError` naming the file, the line
and what was expected.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import TypedDict

import numpy as np

from .errors import BVHError
from .inputs import (
    FRAME_TIME_RANGE,
    MAX_HEADER_CHARS,
    VALUE_LIMIT,
    numbers_only,
    parse_count,
    parse_number,
    read_text_file,
)
from .kinematics import MAX_DEPTH, skeleton_defect
from .motion import POSITION_CHANNELS, ROTATION_CHANNELS, Motion, Skeleton, detect_reference_frame

__all__ = ["read_bvh", "parse_bvh", "write_bvh", "format_bvh"]

_KNOWN_CHANNELS = set(POSITION_CHANNELS) | set(ROTATION_CHANNELS)


class _Tokens:
    """Header tokens with their line numbers."""

    def __init__(self, lines: list[str], source: str) -> None:
        self.items: list[tuple[str, int]] = []
        self.source = source
        for number, line in enumerate(lines, start=1):
            for tok in line.split():
                self.items.append((tok, number))
        self.pos = 0

    def error(self, expected: str, line: int | None = None) -> BVHError:
        if line is None:
            line = self.items[self.pos][1] if self.pos < len(self.items) else self.last_line()
        got = self.items[self.pos][0] if self.pos < len(self.items) else "end of header"
        return BVHError(f"{self.source}:{line}: expected {expected}, got {got!r}")

    def last_line(self) -> int:
        return self.items[-1][1] if self.items else 1

    def next(self, expected: str) -> tuple[str, int]:
        if self.pos >= len(self.items):
            raise self.error(expected)
        item = self.items[self.pos]
        self.pos += 1
        return item

    def expect(self, word: str) -> int:
        tok, line = self.next(repr(word))
        if tok != word:
            self.pos -= 1
            raise self.error(repr(word))
        return line

    def number(self, what: str) -> float:
        tok, line = self.next(what)
        value = parse_number(tok)
        if value is None or abs(value) > VALUE_LIMIT:
            self.pos -= 1
            raise self.error(f"{what} (a finite decimal number within +-{VALUE_LIMIT:g})")
        return value

    def peek(self) -> str | None:
        return self.items[self.pos][0] if self.pos < len(self.items) else None


def _parse_channels(tok: _Tokens) -> list[str]:
    count_tok, _ = tok.next("a channel count")
    count = parse_count(count_tok)
    if count is None or count > len(_KNOWN_CHANNELS):
        tok.pos -= 1
        raise tok.error(f"a channel count (an integer 0..{len(_KNOWN_CHANNELS)})")
    chans: list[str] = []
    for _ in range(count):
        name, _ = tok.next("a channel name")
        if name not in _KNOWN_CHANNELS or name in chans:
            tok.pos -= 1
            raise tok.error("a channel name (Xposition..Zrotation), each at most once a joint")
        chans.append(name)
    return chans


class _Hierarchy(TypedDict):
    """The HIERARCHY section as parsed, before it becomes a `Skeleton`."""

    names: list[str]
    parents: list[int]
    offsets: list[list[float]]
    channels: list[list[str]]
    end_sites: dict[int, np.ndarray]


def _parse_joints(tok: _Tokens, skel: _Hierarchy) -> None:
    """The joint blocks from the root's '{', iteratively (no recursion on hostile depth)."""
    stack: list[int] = []
    opening = 0  # the joint whose '{' comes next
    while True:
        if opening >= 0:
            tok.expect("{")
            if len(stack) >= MAX_DEPTH:
                tok.pos -= 1
                raise tok.error(f"at most {MAX_DEPTH} nested joints")
            stack.append(opening)
            tok.expect("OFFSET")
            skel["offsets"].append([tok.number("an OFFSET number") for _ in range(3)])
            tok.expect("CHANNELS")
            skel["channels"].append(_parse_channels(tok))
            opening = -1
        index = stack[-1]
        word, _ = tok.next("JOINT, End Site or '}'")
        if word == "}":
            stack.pop()
            if not stack:
                return
        elif word == "JOINT":
            name, _ = tok.next("a joint name")
            skel["names"].append(name)
            skel["parents"].append(index)
            opening = len(skel["names"]) - 1
        elif word == "End":
            tok.expect("Site")
            tok.expect("{")
            tok.expect("OFFSET")
            skel["end_sites"][index] = np.array([tok.number("an OFFSET number") for _ in range(3)])
            tok.expect("}")
        else:
            tok.pos -= 1
            raise tok.error("JOINT, End Site or '}'")


def _parse_header(lines: list[str], source: str) -> Skeleton:
    tok = _Tokens(lines, source)
    tok.expect("HIERARCHY")
    tok.expect("ROOT")
    name, _ = tok.next("a root joint name")
    skel: _Hierarchy = {"names": [name], "parents": [-1], "offsets": [], "channels": [],
                        "end_sites": {}}
    _parse_joints(tok, skel)
    if tok.peek() is not None:
        raise tok.error("MOTION after the hierarchy")
    skeleton = Skeleton(skel["names"], skel["parents"], np.array(skel["offsets"]),
                        skel["channels"], end_sites=skel["end_sites"])
    defect = skeleton_defect(skeleton, VALUE_LIMIT)
    if defect:
        raise BVHError(f"{source}:{tok.last_line()}: {defect}")
    return skeleton


_FRAMES = re.compile(r"^\s*Frames\s*:\s*(\S+)\s*$")
_FRAME_TIME = re.compile(r"^\s*Frame\s+Time\s*:\s*(\S+)\s*$")


def _parse_motion_values(lines: list[str], first_line: int, n_frames: int, n_channels: int,
                         source: str) -> np.ndarray:
    rows = [ln for ln in lines if ln.strip()]
    # Blank lines are allowed only at the end of the file.
    body = lines[: max((i for i, ln in enumerate(lines) if ln.strip()), default=-1) + 1]
    if len(body) != len(rows):
        blank = next(i for i, ln in enumerate(body) if not ln.strip())
        raise BVHError(f"{source}:{first_line + blank}: expected a frame of {n_channels} values,"
                       " got a blank line")
    if len(rows) != n_frames:
        line = first_line + min(len(rows), n_frames)
        raise BVHError(f"{source}:{line}: expected {n_frames} frames (the Frames: line),"
                       f" got {len(rows)}")
    for i, row in enumerate(rows):
        count = len(row.split())
        if count != n_channels:
            what = "truncated frame" if i == len(rows) - 1 and count < n_channels else "frame"
            raise BVHError(f"{source}:{first_line + i}: expected {n_channels} values"
                           f" (the CHANNELS of the hierarchy), got {count} ({what})")
    joined = " ".join(rows)
    values = None
    if numbers_only(joined):
        try:
            values = np.array(joined.split(), dtype=np.float64)
        except ValueError:
            pass
    if values is None:
        for i, row in enumerate(rows):
            for col, word in enumerate(row.split()):
                if parse_number(word) is None:
                    raise BVHError(f"{source}:{first_line + i}: expected a finite number in"
                                   f" column {col + 1}, got {word!r}")
        raise AssertionError("unreachable: every word parsed")
    values = values.reshape(n_frames, n_channels)
    bad = ~(np.abs(values) <= VALUE_LIMIT)
    if bad.any():
        i, col = np.argwhere(bad)[0]
        raise BVHError(f"{source}:{first_line + i}: expected a finite number within"
                       f" +-{VALUE_LIMIT:g} in column {col + 1}, got {rows[i].split()[col]!r}")
    return values


def parse_bvh(text: str, source: str = "<string>", name: str = "") -> Motion:
    """Parse BVH text into a `Motion`; `source` names the file in error messages."""
    lines = text.removeprefix("\ufeff").splitlines()  # a byte-order mark some editors write
    motion_at = next((i for i, ln in enumerate(lines) if ln.strip() == "MOTION"), None)
    if motion_at is None:
        raise BVHError(f"{source}:{len(lines) or 1}: expected a MOTION section, found none")
    if sum(len(line) for line in lines[:motion_at]) > MAX_HEADER_CHARS:
        raise BVHError(f"{source}:{motion_at + 1}: expected a hierarchy of at most"
                       f" {MAX_HEADER_CHARS >> 10} KiB before MOTION, got more")
    skeleton = _parse_header(lines[:motion_at], source)
    frames_line = lines[motion_at + 1] if motion_at + 1 < len(lines) else ""
    m = _FRAMES.match(frames_line)
    n_frames = parse_count(m.group(1)) if m else None
    if n_frames is None:
        raise BVHError(f"{source}:{motion_at + 2}: expected 'Frames: N' (N an integer),"
                       f" got {frames_line.strip()!r}")
    time_line = lines[motion_at + 2] if motion_at + 2 < len(lines) else ""
    t = _FRAME_TIME.match(time_line)
    frame_time = parse_number(t.group(1)) if t else None
    low, high = FRAME_TIME_RANGE
    if frame_time is None or not low <= frame_time <= high:
        raise BVHError(f"{source}:{motion_at + 3}: expected 'Frame Time: T' ({low:g} <= T <="
                       f" {high:g} seconds), got {time_line.strip()!r}")
    values = _parse_motion_values(lines[motion_at + 3 :], motion_at + 4, n_frames,
                                  skeleton.n_channels, source)
    fps = 1.0 / frame_time
    if abs(fps - round(fps)) < 0.01:
        fps = float(round(fps))
    return Motion(skeleton, values, fps, detect_reference_frame(skeleton, values), name)


def read_bvh(path: str | os.PathLike[str]) -> Motion:
    """Read a BVH file; raises `BVHError` (missing file, malformed content) naming the line."""
    p = Path(path)
    return parse_bvh(read_text_file(p, "BVH", BVHError), str(p), p.stem)


def _format_joints(skel: Skeleton, out: list[str]) -> None:
    children: list[list[int]] = [[] for _ in skel.names]
    for j, p in enumerate(skel.parents):
        if p >= 0:
            children[p].append(j)
    stack: list[tuple[int, int, bool]] = [(0, 0, False)]
    while stack:
        j, depth, closing = stack.pop()
        pad = "\t" * depth
        if closing:
            if j in skel.end_sites:
                x, y, z = skel.end_sites[j]
                out += [f"{pad}\tEnd Site", f"{pad}\t{{",
                        f"{pad}\t\tOFFSET {x:.6f} {y:.6f} {z:.6f}", f"{pad}\t}}"]
            out.append(f"{pad}}}")
            continue
        kind = "ROOT" if skel.parents[j] < 0 else "JOINT"
        x, y, z = skel.offsets[j]
        out += [f"{pad}{kind} {skel.names[j]}", f"{pad}{{",
                f"{pad}\tOFFSET {x:.6f} {y:.6f} {z:.6f}",
                f"{pad}\tCHANNELS {len(skel.channels[j])} {' '.join(skel.channels[j])}"]
        stack.append((j, depth, True))
        stack += [(c, depth + 1, False) for c in reversed(children[j])]


def format_bvh(motion: Motion, frames: np.ndarray | None = None) -> str:
    """BVH text of `motion` (or of its `frames` rows only); values with 6 decimals."""
    skel = motion.skeleton
    if not skel.bvh_compatible():
        raise BVHError("cannot write an ASF/AMC skeleton (axis pre-rotations or dof order) as"
                       " BVH as is: convert the motion with streamkey.amc.bvh_equivalent")
    out = ["HIERARCHY"]
    _format_joints(skel, out)
    values = motion.channels if frames is None else motion.channels[frames]
    out += ["MOTION", f"Frames: {len(values)}", f"Frame Time: {1.0 / motion.fps:.7f}"]
    text = "\n".join(out) + "\n"
    if len(values):
        body = np.char.mod("%.6f", np.round(values, 6) + 0.0)
        text += "\n".join(" ".join(row) for row in body) + "\n"
    return text


def write_bvh(motion: Motion, path: str | os.PathLike[str],
              frames: np.ndarray | None = None) -> None:
    """Write `motion` (or only the rows `frames`) to a BVH file."""
    Path(path).write_text(format_bvh(motion, frames), encoding="utf-8")
