"""Online-versus-offline agreement: one-to-one matching of keyframes within a
method's tolerance, per clip and against lookahead; and at the default settings of both sides,
per clip and per session (`default_agreement`).

Tolerances of the lookahead table: saliency, sigma frames; speed minima and curve
simplification, 1/4 of the median interval between the offline keyframes (Miura's criterion).
At the defaults every method is matched within ±4 frames of 120 Hz (`MATCH_S`), and the goal
(`GOALS`) is: F1 median >= 0.9 and worst >= 0.75 over the clips, online key count within
0.8-1.25x of offline, optimal's online E <= 1.05x the E of the offline optimum with the same
key count, and on sessions of a minute or more F1 >= 0.95 after the first 10 s (`WARMUP_S`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .evaluate import match_one_to_one
from .keyframes import KeyframeEvent, Keyframes
from .methods import offline_method, online_class
from .motion import Motion

__all__ = ["Agreement", "agreement", "tolerance_for", "online_keyframes", "lookahead_table",
           "write_lookahead_table", "LOOKAHEADS", "METHODS", "MATCH_S", "WARMUP_S", "Goals",
           "GOALS", "default_agreement", "goal_cells"]

LOOKAHEADS = {"saliency": (30, 60, 121, 240), "speed": (30, 60, 90, 120, 240),
              "simplify": (15, 30, 60, 120, 240)}


@dataclass(frozen=True)
class Agreement:
    """One clip, one method, one lookahead: counts, precision, recall, F1, worst latency."""

    method: str
    lookahead: int
    offline: int
    online: int
    precision: float
    recall: float
    f1: float
    max_latency: int


def tolerance_for(method: str, offline: Keyframes) -> float:
    """The matching tolerance in frames for `method`: sigma for saliency, else 1/4 of the
    median interval between the offline keyframes (Miura et al. 2014, §4.4)."""
    if method == "saliency":
        return float(offline.params.get("sigma", 10.0))
    frames = np.asarray(offline.frames)
    if len(frames) < 2:
        return 1.0
    return float(np.median(np.diff(frames))) / 4.0


def online_keyframes(motion: Motion, method: str, lookahead: int | None = None,
                     **params: Any) -> list[KeyframeEvent]:
    """Events of one online keyframer over the whole clip (frames pushed as a stream)."""
    kwargs = dict(params)
    if lookahead is not None:
        kwargs["lookahead"] = lookahead
    keyframer = online_class(method)(motion.skeleton, motion.fps, **kwargs)
    events = keyframer.push_block(motion.frames()) + keyframer.flush()
    return [e for e in events if isinstance(e, KeyframeEvent)]


def agreement(motion: Motion, method: str, lookahead: int | None = None,
              offline: Keyframes | None = None, **params: Any) -> Agreement:
    """Compare the online keyframer with the offline method on one clip."""
    offline = offline if offline is not None else offline_method(method)(motion, **params)
    events = online_keyframes(motion, method, lookahead, **params)
    tp, p, r, f1 = match_one_to_one([e.frame for e in events], offline.frames,
                                    tolerance_for(method, offline))
    used = events[0].lookahead if events else (lookahead or 0)
    return Agreement(method, used, len(offline), len(events), p, r, f1,
                     max((e.latency_frames for e in events), default=0))


def lookahead_table(motions: Sequence[Motion], lookaheads: dict[str, Sequence[int]],
                    params: dict[str, dict[str, Any]] | None = None,
                    progress: Callable[[str], None] | None = None) -> list[dict[str, Any]]:
    """Mean and worst F1 over `motions` for every method and lookahead."""
    rows = []
    params = params or {}
    for method, values in lookaheads.items():
        offline = {id(m): offline_method(method)(m, **params.get(method, {})) for m in motions}
        for lookahead in values:
            if progress:
                progress(f"{method} lookahead {lookahead}")
            scores = [agreement(m, method, lookahead, offline[id(m)], **params.get(method, {}))
                      for m in motions]
            f1 = np.array([s.f1 for s in scores])
            rows.append({"method": method, "lookahead": lookahead,
                         "mean_f1": float(f1.mean()), "min_f1": float(f1.min()),
                         "worst_clip": motions[int(f1.argmin())].name,
                         "max_latency": max(s.max_latency for s in scores)})
    return rows


def write_lookahead_table(rows: list[dict[str, Any]], path: Path) -> None:
    """Markdown of `lookahead_table` rows."""
    lines = ["| method | lookahead (frames) | mean F1 | lowest F1 | lowest clip | max latency |",
             "|---|---:|---:|---:|---|---:|"]
    for r in rows:
        lines.append(f"| {r['method']} | {r['lookahead']} | {r['mean_f1']:.3f} | "
                     f"{r['min_f1']:.3f} | {r['worst_clip']} | {r['max_latency']} |")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


METHODS = ("saliency", "speed", "simplify", "optimal")
MATCH_S = 4.0 / 120.0  # keys within ±4 frames of 120 Hz are the same key
WARMUP_S = 10.0  # sessions: agreement is also measured after the first 10 s


@dataclass(frozen=True)
class Goals:
    """The online = offline goal at the default settings of both sides."""

    f1_median: float = 0.9
    f1_worst: float = 0.75
    ratio_low: float = 0.8
    ratio_high: float = 1.25
    e_ratio: float = 1.05
    session_f1_after: float = 0.95
    session_min_s: float = 60.0


GOALS = Goals()


def _ratio(a: float, b: float) -> float:
    if b > 0:
        return a / b
    return 1.0 if a == 0 else float("inf")


def _e_ratio(motion: Motion, online: np.ndarray) -> float:
    """E of `online`'s keys over E of the offline optimum with as many keys."""
    from .evaluate import Evaluator
    from .methods import optimal

    evaluator = Evaluator(motion)
    count = len(np.unique(online))
    best = evaluator.score(optimal.extract(motion, count=count)).error
    return _ratio(evaluator.score(online).error, best)


def default_agreement(motion: Motion, methods: Sequence[str] = METHODS, *, kind: str = "clip",
                      after_s: float | None = None) -> list[dict[str, Any]]:
    """Online (the default keyframers on one pipeline, as `extract --online`) against offline
    (the default methods), one row a method: key counts, F1 within `MATCH_S`, the key-count
    ratio, optimal's E ratio at the same key count and, with `after_s`, F1 and the key-count
    ratio over the keys at or after `after_s` seconds."""
    from .robustness import offline_keys, online_keys

    offline = offline_keys(motion, methods)
    online = online_keys(motion, methods)
    tol = MATCH_S * motion.fps
    start = int(np.ceil((after_s or 0.0) * motion.fps - 1e-9)) + motion.first_frame
    rows = []
    for method in methods:
        off, on = offline[method], online[method]
        row: dict[str, Any] = {
            "name": motion.name, "kind": kind,
            "frames": motion.n_frames - motion.first_frame,
            "seconds": (motion.n_frames - motion.first_frame) / motion.fps,
            "method": method, "offline": len(off), "online": len(on),
            "f1": match_one_to_one(on, off, tol)[3], "count_ratio": _ratio(len(on), len(off)),
            "e_ratio": _e_ratio(motion, on) if method == "optimal" else None,
            "f1_after": None, "count_ratio_after": None}
        if after_s is not None:
            off_a, on_a = off[off >= start], on[on >= start]
            row["f1_after"] = match_one_to_one(on_a, off_a, tol)[3]
            row["count_ratio_after"] = _ratio(len(on_a), len(off_a))
        rows.append(row)
    return rows


def _worst(rows: Sequence[Mapping[str, Any]], key: str, high: bool = False) -> tuple[float, str]:
    values = [(float(r[key]), str(r["name"])) for r in rows if r[key] is not None]
    return max(values) if high else min(values)


def goal_cells(rows: Sequence[Mapping[str, Any]], goals: Goals = GOALS
               ) -> dict[tuple[str, str, str], tuple[bool, str]]:
    """Each goal check of `default_agreement` rows: {(kind, method, check): (met, measured)}.

    Checks: clips `f1` (median and worst), `key count` (every clip in range), `E ratio`
    (optimal, every clip); sessions of at least `goals.session_min_s` `f1 after 10 s`."""
    cells: dict[tuple[str, str, str], tuple[bool, str]] = {}
    for method in dict.fromkeys(str(r["method"]) for r in rows):
        clips = [r for r in rows if r["method"] == method and r["kind"] == "clip"]
        sessions = [r for r in rows if r["method"] == method and r["kind"] == "session"
                    and float(r["seconds"]) >= goals.session_min_s]
        if clips:
            median = float(np.median([r["f1"] for r in clips]))
            low, low_name = _worst(clips, "f1")
            cells[("clip", method, "f1")] = (
                median >= goals.f1_median and low >= goals.f1_worst,
                f"F1 median {median:.3f}, worst {low:.3f} ({low_name})")
            rlow, rlow_name = _worst(clips, "count_ratio")
            rhigh, rhigh_name = _worst(clips, "count_ratio", high=True)
            cells[("clip", method, "key count")] = (
                goals.ratio_low <= rlow and rhigh <= goals.ratio_high,
                f"key ratio {rlow:.2f} ({rlow_name}) to {rhigh:.2f} ({rhigh_name})")
            if method == "optimal":
                ehigh, ehigh_name = _worst(clips, "e_ratio", high=True)
                cells[("clip", method, "E ratio")] = (
                    ehigh <= goals.e_ratio, f"E ratio worst {ehigh:.3f} ({ehigh_name})")
        if sessions:
            low, low_name = _worst(sessions, "f1_after")
            cells[("session", method, "f1 after 10 s")] = (
                low >= goals.session_f1_after, f"F1 after 10 s worst {low:.3f} ({low_name})")
    return cells
