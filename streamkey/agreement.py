"""Online-versus-offline agreement: one-to-one matching of keyframes within a
method's tolerance, per clip and against lookahead.

Tolerances: saliency, sigma frames; speed minima and curve simplification, 1/4 of the median
interval between the offline keyframes (Miura's criterion).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .evaluate import match_one_to_one
from .keyframes import KeyframeEvent, Keyframes
from .methods import offline_method, online_class
from .motion import Motion

__all__ = ["Agreement", "agreement", "tolerance_for", "online_keyframes", "lookahead_table",
           "write_lookahead_table", "LOOKAHEADS"]

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
