"""Strict, fast BVH reader and writer.

Accepts the usual variants (any rotation order, end sites, CRLF, tabs or spaces, `Frame Time`
with or without a leading zero). Every defect raises one `BVHError` naming the file, the line
and what was expected.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from .errors import BVHError
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
        try:
            value = float(tok)
        except ValueError:
            self.pos -= 1
            raise self.error(what) from None
        if not np.isfinite(value):
            self.pos -= 1
            raise self.error(f"a finite {what}")
        return value

    def peek(self) -> str | None:
        return self.items[self.pos][0] if self.pos < len(self.items) else None


def _parse_joint(tok: _Tokens, parent: int, skel: dict[str, list]) -> None:
    tok.expect("{")
    index = len(skel["names"]) - 1
    tok.expect("OFFSET")
    skel["offsets"].append([tok.number("an OFFSET number") for _ in range(3)])
    tok.expect("CHANNELS")
    count_tok, count_line = tok.next("a channel count")
    if not count_tok.isdigit():
        tok.pos -= 1
        raise tok.error("a channel count (integer)")
    chans = []
    for _ in range(int(count_tok)):
        name, line = tok.next("a channel name")
        if name not in _KNOWN_CHANNELS:
            tok.pos -= 1
            raise tok.error("a channel name (Xposition..Zrotation)")
        chans.append(name)
    skel["channels"].append(chans)
    while True:
        word, line = tok.next("JOINT, End Site or '}'")
        if word == "}":
            return
        if word == "JOINT":
            name, _ = tok.next("a joint name")
            skel["names"].append(name)
            skel["parents"].append(index)
            _parse_joint(tok, index, skel)
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
    skel: dict[str, list] = {"names": [name], "parents": [-1], "offsets": [], "channels": [],
                             "end_sites": {}}
    _parse_joint(tok, -1, skel)
    if tok.peek() is not None:
        raise tok.error("MOTION after the hierarchy")
    return Skeleton(skel["names"], skel["parents"], np.array(skel["offsets"]), skel["channels"],
                    end_sites=skel["end_sites"])


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
    try:
        values = np.array(" ".join(rows).split(), dtype=np.float64)
    except ValueError:
        for i, row in enumerate(rows):
            for col, word in enumerate(row.split()):
                try:
                    float(word)
                except ValueError:
                    raise BVHError(f"{source}:{first_line + i}: expected a number in column"
                                   f" {col + 1}, got {word!r}") from None
        raise
    values = values.reshape(n_frames, n_channels) if n_frames else values.reshape(0, n_channels)
    bad = ~np.isfinite(values)
    if bad.any():
        i, col = np.argwhere(bad)[0]
        raise BVHError(f"{source}:{first_line + i}: expected a finite number in column"
                       f" {col + 1}, got {rows[i].split()[col]!r}")
    return values


def parse_bvh(text: str, source: str = "<string>", name: str = "") -> Motion:
    """Parse BVH text into a `Motion`; `source` names the file in error messages."""
    lines = text.splitlines()
    motion_at = next((i for i, ln in enumerate(lines) if ln.strip() == "MOTION"), None)
    if motion_at is None:
        raise BVHError(f"{source}:{len(lines) or 1}: expected a MOTION section, found none")
    skeleton = _parse_header(lines[:motion_at], source)
    frames_line = lines[motion_at + 1] if motion_at + 1 < len(lines) else ""
    m = _FRAMES.match(frames_line)
    if not m or not m.group(1).isdigit():
        raise BVHError(f"{source}:{motion_at + 2}: expected 'Frames: N' (N an integer),"
                       f" got {frames_line.strip()!r}")
    n_frames = int(m.group(1))
    time_line = lines[motion_at + 2] if motion_at + 2 < len(lines) else ""
    t = _FRAME_TIME.match(time_line)
    try:
        frame_time = float(t.group(1)) if t else float("nan")
    except ValueError:
        frame_time = float("nan")
    if not (np.isfinite(frame_time) and frame_time > 0):
        raise BVHError(f"{source}:{motion_at + 3}: expected 'Frame Time: T' (T > 0 seconds),"
                       f" got {time_line.strip()!r}")
    values = _parse_motion_values(lines[motion_at + 3 :], motion_at + 4, n_frames,
                                  skeleton.n_channels, source)
    fps = 1.0 / frame_time
    if abs(fps - round(fps)) < 0.01:
        fps = float(round(fps))
    return Motion(skeleton, values, fps, detect_reference_frame(skeleton, values), name)


def read_bvh(path: str | os.PathLike[str]) -> Motion:
    """Read a BVH file; raises `BVHError` (missing file, malformed content) naming the line."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8", errors="strict")
    except FileNotFoundError:
        raise BVHError(f"{p}: no such file") from None
    except IsADirectoryError:
        raise BVHError(f"{p}: is a directory, expected a BVH file") from None
    except UnicodeDecodeError as exc:
        raise BVHError(f"{p}: expected a text file, got undecodable bytes ({exc.reason})") from None
    return parse_bvh(text, str(p), p.stem)


def _format_joint(skel: Skeleton, j: int, depth: int, out: list[str]) -> None:
    pad = "\t" * depth
    kind = "ROOT" if skel.parents[j] < 0 else "JOINT"
    out.append(f"{pad}{kind} {skel.names[j]}")
    out.append(f"{pad}{{")
    x, y, z = skel.offsets[j]
    out.append(f"{pad}\tOFFSET {x:.6f} {y:.6f} {z:.6f}")
    out.append(f"{pad}\tCHANNELS {len(skel.channels[j])} {' '.join(skel.channels[j])}")
    for c in skel.children(j):
        _format_joint(skel, c, depth + 1, out)
    if j in skel.end_sites:
        x, y, z = skel.end_sites[j]
        out += [f"{pad}\tEnd Site", f"{pad}\t{{", f"{pad}\t\tOFFSET {x:.6f} {y:.6f} {z:.6f}",
                f"{pad}\t}}"]
    out.append(f"{pad}}}")


def format_bvh(motion: Motion, frames: np.ndarray | None = None) -> str:
    """BVH text of `motion` (or of its `frames` rows only); values with 6 decimals."""
    skel = motion.skeleton
    if any(p is not None for p in (skel.pre_rotations or [])):
        raise BVHError("cannot write an ASF/AMC skeleton with axis pre-rotations as BVH")
    out = ["HIERARCHY"]
    _format_joint(skel, 0, 0, out)
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
