"""`streamkey bench --playable`: how early provisional events come and how many are taken back,
per online method over a folder of clips (the README table), with the promises checked: the
final keys are those of a run without provisional events, each provisional is resolved once.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ..keyframes import CancelEvent, KeyframeEvent, ProvisionalEvent

__all__ = ["measure", "bench_playable"]


def measure(motion: Any, method: str, params: dict[str, Any] | None = None
            ) -> dict[str, list[float]]:
    """One clip, one method, provisional events on: per confirmed provisional its lead (ms,
    final decision minus announcement), per provisional whether it was cancelled and its
    pose-to-announcement delay (ms), per final key its pose-to-event delay (ms). `mismatch`
    counts broken promises (must be 0): final keys that differ from a run without provisional
    events (run alongside), provisionals not resolved exactly once."""
    from ..online import Pipeline
    from ..streaming import make_keyframers

    opts = {**(params or {}), "*": {"provisional": True}}
    pipeline = Pipeline(make_keyframers(motion, [method], params, stream="plain")
                        + make_keyframers(motion, [method], opts))
    both = pipeline.push_block(motion.frames()) + pipeline.flush()
    plain = [e for e in both if isinstance(e, KeyframeEvent) and e.stream == "plain"]
    events = [e for e in both if getattr(e, "stream", None) != "plain"]
    ms = 1000.0 / motion.fps
    seen = {e.pid: e.seen_at for e in events if isinstance(e, ProvisionalEvent)}
    keys = [e for e in events if isinstance(e, KeyframeEvent)]
    cancels = [e for e in events if isinstance(e, CancelEvent)]
    resolved = sorted([e.confirms for e in keys] + [e.pid for e in cancels],
                      key=lambda pid: -1 if pid is None else pid)
    same = [(e.frame, e.decided_at, e.score) for e in keys] == [
        (e.frame, e.decided_at, e.score) for e in plain]
    return {"announce_ms": [(e.seen_at - e.frame) * ms for e in events
                            if isinstance(e, ProvisionalEvent)],
            "lead_ms": [(e.decided_at - seen[e.confirms]) * ms for e in keys
                        if e.confirms is not None],
            "cancelled": [1.0] * len(cancels) + [0.0] * len(keys),
            "delay_ms": [e.latency_frames * ms for e in keys],
            "mismatch": [float(not same) + float(resolved != sorted(seen))]}


def bench_playable(data: Path, output: Path) -> list[Path]:
    """`bench --playable`: the provisional lead, cancel share and pose-to-event delay per
    online method over every clip of `data`; writes bench_playable.json and .md."""
    from ..batch import find_motion_files, load_motion
    from ..methods import ONLINE_METHODS

    paths = find_motion_files([str(data)])
    rows: dict[str, dict[str, Any]] = {}
    for method in ONLINE_METHODS:
        acc: dict[str, list[float]] = {"lead_ms": [], "cancelled": [], "delay_ms": [],
                                       "announce_ms": [], "mismatch": []}
        for path in paths:
            for k, v in measure(load_motion(path), method).items():
                acc[k] += v
        lead = np.array(acc["lead_ms"])
        rows[method] = {
            "provisionals": len(acc["cancelled"]), "keys": len(acc["delay_ms"]),
            "clips_with_a_broken_promise": int(np.count_nonzero(acc["mismatch"])),
            "median_lead_ms": float(np.median(lead)) if len(lead) else None,
            "early_share": float(np.mean(lead > 0)) if len(lead) else None,
            "cancel_share": float(np.mean(acc["cancelled"])) if acc["cancelled"] else None,
            "median_delay_ms": float(np.median(acc["delay_ms"])) if acc["delay_ms"] else None,
            "median_announce_ms": (float(np.median(acc["announce_ms"])) if acc["announce_ms"]
                                   else None)}
    output.mkdir(parents=True, exist_ok=True)
    result = {"clips": len(paths), "methods": rows,
              "note": "default parameters and lookahead; lead = decided_at - seen_at of the "
                      "provisional each final key confirms (0 when it had none before); "
                      "clips_with_a_broken_promise: final keys unlike a run without "
                      "provisional events, or a provisional not resolved exactly once"}
    broken = sum(r["clips_with_a_broken_promise"] for r in rows.values())
    lines = [f"Provisional events over {len(paths)} clips (default parameters); final keys "
             f"as without provisional events and every provisional resolved exactly once: "
             f"{'yes' if broken == 0 else f'NO ({broken} clip-method pairs)'}", "",
             "| method | median provisional lead (ms) | announced early | cancelled | "
             "median pose-to-provisional (ms) | median pose-to-final delay (ms) | keys | "
             "provisionals |", "|---|---|---|---|---|---|---|---|"]
    for m, r in rows.items():
        lines.append(f"| {m} | {r['median_lead_ms']:.0f} | {100 * r['early_share']:.0f} % | "
                     f"{100 * r['cancel_share']:.0f} % | {r['median_announce_ms']:.0f} | "
                     f"{r['median_delay_ms']:.0f} | {r['keys']} | {r['provisionals']} |")
    written = []
    for suffix, text in (("json", json.dumps(result, indent=1)), ("md", "\n".join(lines))):
        path = output / f"bench_playable.{suffix}"
        path.write_text(text + "\n", encoding="utf-8")
        written.append(path)
    return written
