"""Online keyframers run over recorded motion as if it were streamed (`extract --online`)."""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from typing import Any

import numpy as np

from . import playable_online
from .errors import UsageError
from .filters import DEFAULT_NOISE_CUTOFF_HZ
from .keyframes import KeyframeEvent, Keyframes, Segment, SegmentEvent
from .methods import online_class
from .methods.params import to_method_units
from .motion import Motion
from .online import OnlineKeyframer, Pipeline
from .playable import parse_min_interval
from .units import DurationLike

__all__ = ["make_keyframers", "noise_cutoff", "run_online", "run_online_with_segments",
           "check_online_params", "common_params", "MinIntervalLike"]

# `min_interval`: seconds for every method, {method or "*": seconds}, or the CLI's text
MinIntervalLike = float | Mapping[str, float] | str | None


def common_params(params: dict[str, dict[str, Any]] | None, max_gap: float | None = None,
                  min_interval: MinIntervalLike = None) -> dict[str, dict[str, Any]]:
    """`params` with `max_gap` (seconds) and `min_interval` put in `params["*"]`, the options
    every method shares; a value given here wins over one already there."""
    out = dict(params or {})
    common = dict(out.get("*", {}))
    if max_gap is not None:
        common["max_gap"] = max_gap
    if isinstance(min_interval, str):
        min_interval = parse_min_interval(min_interval)
    if isinstance(min_interval, int | float):
        min_interval = {"*": float(min_interval)}
    if min_interval is not None:
        common["min_interval"] = dict(min_interval)
    out["*"] = common
    return out


def check_online_params(methods: list[str], params: dict[str, dict[str, Any]] | None) -> None:
    """Refuse, before anything runs, a parameter that a chosen online keyframer cannot honour
    (e.g. `--count` for online simplify, which decides by tolerance as frames arrive)."""
    counted = [m for m in methods if (params or {}).get(m, {}).get("count") is not None]
    if counted:
        raise UsageError(f"--count: online {' and '.join(counted)} cannot aim at a key count "
                         "(it needs the whole take); give a tolerance (simplify) or --rate "
                         "(optimal) instead; counts are offline (extract without --online)")
    for name in methods:
        given = [k for k, v in (params or {}).get(name, {}).items() if v is not None]
        accepted = inspect.signature(online_class(name)).parameters
        if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in accepted.values()):
            continue
        unknown = [k for k in given if k not in accepted]
        if unknown:
            flags = ", ".join("--" + k.replace("_", "-") for k in unknown)
            raise UsageError(f"{name} online does not take {flags}; choose other methods with "
                             f"--method or leave {flags} out")


def _bridge_frames(common: dict[str, Any], fps: float) -> int | None:
    """The gap-bridging limit in frames from `max_bridge_frames` or `max_bridge_seconds`."""
    if common.get("max_bridge_frames") is not None:
        return int(common["max_bridge_frames"])
    if common.get("max_bridge_seconds") is not None:
        return int(round(float(common["max_bridge_seconds"]) * fps))
    return None


def noise_cutoff(params: dict[str, dict[str, Any]] | None) -> float | None:
    """The sensor-noise cut-off `params["*"]["noise_cutoff_hz"]` asks for (None or 0: off);
    not given: the library default, `filters.DEFAULT_NOISE_CUTOFF_HZ`."""
    common = (params or {}).get("*", {})
    return common.get("noise_cutoff_hz", DEFAULT_NOISE_CUTOFF_HZ) or None


def make_keyframers(motion: Motion, methods: list[str],
                    params: dict[str, dict[str, Any]] | None = None,
                    lookahead: DurationLike | None = None, stream: str = "default"
                    ) -> list[OnlineKeyframer]:
    """One online keyframer per method name, with its parameters and optional lookahead
    (`params[name]["lookahead"]` wins; a `Duration` in seconds becomes frames at the motion's
    rate, as every duration parameter does); `params["*"]["max_gap"]` (seconds) wraps each in
    `optimal.MaxGap`, `params["*"]["max_bridge_frames"]` or `["max_bridge_seconds"]` sets the
    longest interpolated hole of every keyframer (and so of a `Pipeline` of them), and
    `params["*"]["noise_cutoff_hz"]` the input low-pass of each (`noise_cutoff`: not given,
    the library default; None or 0: off)."""
    params = params or {}
    common = params.get("*", {})
    max_gap = common.get("max_gap")
    bridge = _bridge_frames(common, motion.fps)
    cutoff = noise_cutoff(params)
    check_online_params(methods, params)
    out = []
    for name in methods:
        kwargs = {k: v for k, v in params.get(name, {}).items() if v is not None}
        if lookahead is not None:
            kwargs.setdefault("lookahead", lookahead)
        kwargs = to_method_units(name, kwargs, motion.fps)  # durations in seconds -> frames
        if bridge is not None:
            kwargs["max_bridge_frames"] = bridge
        kf = online_class(name)(motion.skeleton, motion.fps, stream=stream, **kwargs)
        if cutoff != kf.features.noise_cutoff_hz:
            kf.features.configure(cutoff)
        if max_gap is not None:
            from .methods.optimal import MaxGap

            kf = MaxGap(kf, max_gap)
        out.append(playable_online.wrap(kf, params.get("*", {})))
    playable_online.link_signal(out)
    return out


def run_online(motion: Motion, methods: list[str],
               params: dict[str, dict[str, Any]] | None = None,
               lookahead: DurationLike | None = None, *, max_gap: float | None = None,
               min_interval: MinIntervalLike = None) -> dict[str, Keyframes]:
    """Push every captured frame of `motion` through the online keyframers, then flush.
    `max_gap` and `min_interval` as for `batch.extract_motion` (here the keyframers apply
    them as frames arrive)."""
    return run_online_with_segments(motion, methods, params, lookahead, max_gap=max_gap,
                                    min_interval=min_interval)[0]


def run_online_with_segments(motion: Motion, methods: list[str],
                             params: dict[str, dict[str, Any]] | None = None,
                             lookahead: DurationLike | None = None, *,
                             max_gap: float | None = None, min_interval: MinIntervalLike = None
                             ) -> tuple[dict[str, Keyframes], list[Segment] | None]:
    """`run_online`, and the session segments the pipeline sent as it went (closed
    `SegmentEvent`s; None when the skeleton lacks the joints the detector reads)."""
    params = common_params(params, max_gap, min_interval)
    keyframers = make_keyframers(motion, methods, params, lookahead)
    pipeline = Pipeline(keyframers)
    events = pipeline.push_block(motion.frames()) + pipeline.flush()
    segments = None if pipeline.segments is None else [
        e.segment() for e in events if isinstance(e, SegmentEvent) and e.end is not None]
    out = {}
    for kf in keyframers:
        mine = sorted((e for e in events if isinstance(e, KeyframeEvent) and e.method == kf.method),
                      key=lambda e: e.frame)
        latency = [e.latency_frames for e in mine]
        out[kf.method] = Keyframes(
            kf.method, np.array([e.frame for e in mine], dtype=np.int64),
            np.array([e.score for e in mine]), {**kf.params, "online": True}, motion.n_frames,
            info={"latency_frames_max": max(latency, default=0), "lookahead": kf.lookahead},
            strength=[e.strength for e in mine])
    return out, segments
