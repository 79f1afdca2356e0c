"""Text mutations of BVH/ASF/AMC files, shared by the fuzz tests and the fuzz campaign.

A mutation is a list of `(kind, where, payload)` operations applied in order; `where` in
[0, 1) picks the line, token or byte, so hypothesis can shrink them and a seeded
`random.Random` can draw them alike. The payloads are the hostile review's classes: non-ASCII
digits, huge, tiny, negative and non-finite numbers, structure words out of place, empty and
binary text.
"""

from __future__ import annotations

import random
import re
from pathlib import Path

from cmu import DATA

__all__ = ["KINDS", "PAYLOADS", "apply", "random_ops", "base_texts", "write_case"]

KINDS = ("token", "line_delete", "line_duplicate", "line_swap", "truncate", "insert",
         "number_scale", "number", "number", "number", "frames", "frames", "still")
PAYLOADS = ("\u00b2", "\u0663", "1e308", "-1e308", "1e-300", "5e-324", "0", "-0", "nan", "inf",
            "-inf", "1_0", "99999999999", "100", "4", "7", "-1", "{", "}", "JOINT x", "End Site",
            "CHANNELS", "OFFSET", "MOTION", "Frames: 0", "Frame Time: 100", ":DEGREES",
            "root", "begin", "end", "", "\t", "\x00", "\ufeff", "\u00e9", "e", "+", ".")
NUMBERS = ("1e308", "-1e308", "5e-324", "1e-300", "0", "-0", "100", "10", "1e6", "-1e6",
           "99999999999", "\u00b2", "\u0663", "nan", "1_0", "0.00001", "3")
_TOKEN = re.compile(r"\S+")
_NUMBER = re.compile(r"(?<![\w.])-?\d+(?:\.\d+)?(?:e-?\d+)?(?![\w.])")


def _at(seq_len: int, where: float) -> int:
    return min(int(where * seq_len), max(seq_len - 1, 0))


def apply(text: str, ops: list[tuple[str, float, str]]) -> str:
    """`text` with every operation applied in order."""
    for kind, where, payload in ops:
        lines = text.split("\n")
        i = _at(len(lines), where)
        if kind == "token":
            spans = [m.span() for m in _TOKEN.finditer(text)]
            if spans:
                a, b = spans[_at(len(spans), where)]
                text = text[:a] + payload + text[b:]
        elif kind == "line_delete":
            text = "\n".join(lines[:i] + lines[i + 1:])
        elif kind == "line_duplicate":
            text = "\n".join(lines[:i + 1] + lines[i:])
        elif kind == "line_swap" and i + 1 < len(lines):
            lines[i], lines[i + 1] = lines[i + 1], lines[i]
            text = "\n".join(lines)
        elif kind == "truncate":
            text = text[:_at(len(text) + 1, where)]
        elif kind == "insert":
            at = _at(len(text) + 1, where)
            text = text[:at] + payload + text[at:]
        elif kind == "number":
            spans = [m.span() for m in _NUMBER.finditer(text)]
            if spans:
                a, b = spans[_at(len(spans), where)]
                text = text[:a] + NUMBERS[_at(len(NUMBERS), (where * 7919) % 1)] + text[b:]
        elif kind == "frames":
            text = _keep_frames(text, _at(7, where))
        elif kind == "still":
            text = _still(text)
        elif kind == "number_scale":
            spans = [m.span() for m in re.finditer(r"-?\d+\.\d+", text)]
            if spans:
                a, b = spans[_at(len(spans), where)]
                text = text[:a] + f"{float(text[a:b]) * 1e7:g}" + text[b:]
    return text


def _keep_frames(text: str, n: int) -> str:
    """Only the first `n` frames, the Frames: line agreeing (BVH), or n frames (AMC)."""
    if "MOTION\n" in text:
        head, body = text.split("MOTION\n", 1)
        rows = body.split("\n")
        if len(rows) < 2:
            return text
        return head + f"MOTION\nFrames: {n}\n{rows[1]}\n" + "".join(
            r + "\n" for r in rows[2:2 + n])
    return _cut_amc(text, n) if re.search(r"^\s*1\s*$", text, re.M) else text


def _still(text: str) -> str:
    """Every frame a copy of the first (BVH): a still pose."""
    if "MOTION\n" not in text:
        return text
    head, body = text.split("MOTION\n", 1)
    rows = body.split("\n")
    frames = [r for r in rows[2:] if r.strip()]
    if not frames:
        return text
    return head + "MOTION\n" + "\n".join(rows[:2]) + "\n" + (frames[0] + "\n") * len(frames)


def random_ops(rng: random.Random, max_ops: int = 3) -> list[tuple[str, float, str]]:
    """1..max_ops random operations (what the campaign draws)."""
    return [(rng.choice(KINDS), rng.random(), rng.choice(PAYLOADS))
            for _ in range(rng.randint(1, max_ops))]


def _cut_bvh(text: str, frames: int) -> str:
    head, body = text.split("MOTION\n", 1)
    rows = body.splitlines()
    return head + f"MOTION\nFrames: {frames}\n{rows[1]}\n" + "\n".join(rows[2:2 + frames]) + "\n"


def _cut_amc(text: str, frames: int) -> str:
    out, seen = [], 0
    for line in text.splitlines():
        if line.strip().isascii() and line.strip().isdigit():
            seen += 1
            if seen > frames:
                break
        out.append(line)
    return "\n".join(out) + "\n"


def base_texts(frames: int = 150) -> dict[str, str]:
    """Real clips cut to `frames` frames: {file name: text}, BVH and one ASF/AMC pair."""
    out = {name: _cut_bvh((DATA / name).read_text(), frames)
           for name in ("07_01.bvh", "16_11.bvh", "131_03.bvh")}
    out["09.asf"] = (DATA / "09.asf").read_text()
    out["09_06.amc"] = _cut_amc((DATA / "09_06.amc").read_text(), frames)
    return out


def write_case(folder: Path, bases: dict[str, str], which: str,
               ops: list[tuple[str, float, str]]) -> Path:
    """Write one mutated case into `folder` (an AMC case gets its ASF, one of them mutated);
    returns the path to give the CLI."""
    folder.mkdir(parents=True, exist_ok=True)
    if which == "09.asf":
        (folder / "09.asf").write_text(apply(bases["09.asf"], ops), encoding="utf-8")
        (folder / "09_06.amc").write_text(bases["09_06.amc"], encoding="utf-8")
        return folder / "09_06.amc"
    if which == "09_06.amc":
        (folder / "09.asf").write_text(bases["09.asf"], encoding="utf-8")
    path = folder / which
    path.write_text(apply(bases[which], ops), encoding="utf-8", errors="surrogatepass")
    return path
