"""How much a method's keys depend on the recording rather than on the motion.

Each clip's clean take is keyed once per mode (offline methods on the whole take; online
keyframers fed the take as a stream). Then every variant of the same take (another rate,
sensor noise, a calibration hold before it, stillness after it, lost frames, and, online
only, faults of the sender's clock) is keyed the same way, its keys inside the take are
mapped back to clean-take frames and compared with the clean take's keys:

- F1 of one-to-one matching within ±4 frames of 120 Hz (`variants.f1_against`);
- key-count ratio (variant's keys in the take over the clean take's keys);
- E ratio: the clean motion rebuilt from the variant's keys (mapped back, rounded, clipped
  to the take, duplicates merged) against the clean motion rebuilt from its own keys, each
  scored by the thesis' error E (`evaluate.Evaluator`).

Lost frames are offered as a real receiver sees them: online, the clean frames are streamed
with the lost sequence numbers missing, so the stream guard bridges the holes; offline, the
take with the holes bridged linearly. Sender clock faults change `Frame.time` only (sequence
numbers intact): a keyframer that decides on sequence numbers gives the clean keys exactly.

Pure computation on `Motion`s: no files, no clocks except the optional per-case timing.
"""

from __future__ import annotations

import time as _time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from .errors import UsageError
from .evaluate import Evaluator, _unwrapped, reconstruct
from .motion import Frame, Motion
from .variants import (
    Variant,
    clean_take,
    f1_against,
    keys_in_take,
    resample,
    with_calibration,
    with_drops,
    with_noise,
    with_stillness,
)

__all__ = ["METHODS", "MODES", "CASES", "STANDARD", "TIMING_CASES", "GOALS", "Case",
           "build_case", "offline_keys", "online_keys", "measure_clip", "measure",
           "summarise", "acceptance"]

METHODS = ("saliency", "speed", "simplify", "optimal")
MODES = ("offline", "online")
JITTER_S = 0.004  # arrival jitter: Gaussian sigma of the sender's time stamps (s)
CLOCK_STEP_S = -1.0  # the sender's clock set back by one second halfway through the take

# Every variant the bench knows, in table order (names as `variants` spells them).
CASES = ("30 Hz", "60 Hz", "90 Hz", "100 Hz", "240 Hz", "noise 0.1°", "noise 0.3°", "noise 1°",
         "calibration before", "stillness after", "1% dropped", "5% dropped",
         "arrival jitter", "clock step")
# The variants of the invariance goal (`variants.standard_variants`).
STANDARD = ("60 Hz", "30 Hz", "noise 0.3°", "calibration before", "stillness after",
            "1% dropped")
TIMING_CASES = ("arrival jitter", "clock step")  # online only: only `Frame.time` changes


@dataclass(frozen=True)
class Goals:
    """The invariance goal: F1 floors for the methods that find poses (saliency, speed),
    a key-count band for every method, an E ceiling for the methods that fit the curve."""

    f1_methods: tuple[str, ...] = ("saliency", "speed")
    f1_mean: float = 0.9
    f1_worst: float = 0.75
    ratio_low: float = 0.8
    ratio_high: float = 1.25
    e_methods: tuple[str, ...] = ("simplify", "optimal")
    e_ratio: float = 1.10


GOALS = Goals()


@dataclass(frozen=True)
class Case:
    """One variant as the bench runs it: `variant` is what offline methods see (and where the
    take lies in it); `stream`, when set, is the online stream instead of the variant's own
    frames; `online_only` cases change nothing an offline method reads."""

    name: str
    variant: Variant
    stream: list[Frame] | None = None
    online_only: bool = False


def _retimed(motion: Motion, times: np.ndarray) -> list[Frame]:
    return [Frame(f.seq, float(t), f.channels)
            for f, t in zip(motion.frames(), times, strict=True)]


def build_case(motion: Motion, name: str, seed: int = 0) -> Case:
    """The variant `name` (one of `CASES`) of `motion`'s take."""
    if name.endswith(" Hz"):
        return Case(name, resample(motion, float(name[:-3])))
    if name.startswith("noise "):
        return Case(name, with_noise(motion, float(name[6:].rstrip("°")), seed))
    if name == "calibration before":
        return Case(name, with_calibration(motion))
    if name == "stillness after":
        return Case(name, with_stillness(motion))
    if name.endswith("% dropped"):
        bridged, lost = with_drops(motion, float(name.split("%")[0]) / 100.0, seed)
        gone = set(lost.tolist())
        stream = [f for f in clean_take(motion).motion.frames() if f.seq not in gone]
        return Case(name, bridged, stream)
    if name in TIMING_CASES:
        clean = clean_take(motion)
        n = clean.motion.n_frames
        times = np.arange(n) / clean.motion.fps
        if name == "arrival jitter":
            times = times + np.random.default_rng(seed).normal(0.0, JITTER_S, n)
        else:
            times[n // 2 :] += CLOCK_STEP_S
        return Case(name, clean, _retimed(clean.motion, times), online_only=True)
    raise UsageError(f"unknown robustness variant {name!r}; choose from {', '.join(CASES)}")


def offline_keys(motion: Motion, methods: Sequence[str]) -> dict[str, np.ndarray]:
    """Frames of each offline method's keys on `motion` (features computed once)."""
    from .features import compute_features
    from .methods import offline_method

    features = compute_features(motion)
    return {m: np.asarray(offline_method(m)(motion, features=features).frames, dtype=np.int64)
            for m in methods}


def online_keys(motion: Motion, methods: Sequence[str],
                stream: Iterable[Frame] | None = None) -> dict[str, np.ndarray]:
    """Frames of each online keyframer's keys, all on one pipeline fed `stream` (default:
    every captured frame of `motion`), then flushed: what `extract --online` does."""
    from .keyframes import KeyframeEvent
    from .online import Pipeline
    from .streaming import make_keyframers

    pipeline = Pipeline(make_keyframers(motion, list(methods)))
    frames = motion.frames() if stream is None else stream
    events = pipeline.push_block(frames) + pipeline.flush()
    out: dict[str, list[int]] = {m: [] for m in methods}
    for e in events:
        if isinstance(e, KeyframeEvent):
            out[e.method].append(e.frame)
    return {m: np.unique(np.asarray(v, dtype=np.int64)) for m, v in out.items()}


def _keys(mode: str, motion: Motion, methods: Sequence[str],
          stream: list[Frame] | None = None) -> dict[str, np.ndarray]:
    if mode == "offline":
        return offline_keys(motion, methods)
    if mode == "online":
        return online_keys(motion, methods, stream)
    raise UsageError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")


def _rows_of(mapped: np.ndarray, n: int) -> np.ndarray:
    """Fractional clean frames as distinct whole frames of the take (at least one)."""
    rows = np.unique(np.clip(np.rint(mapped), 0, n - 1).astype(np.int64))
    return rows if len(rows) else np.zeros(1, dtype=np.int64)


def _ratio(a: float, b: float) -> float:
    if b > 0:
        return a / b
    return 1.0 if a == 0 else float("inf")


def measure_clip(motion: Motion, methods: Sequence[str] = METHODS,
                 modes: Sequence[str] = MODES, cases: Sequence[str] = CASES,
                 progress: Callable[[str], None] | None = None, seed: int = 0
                 ) -> list[dict[str, object]]:
    """One row per (mode, case, method) for `motion`'s take: clean and variant key counts,
    F1, key ratio, E of both reconstructions and their ratio, whether the keys are the
    clean keys exactly, and the seconds the case took (all methods of the mode together)."""
    clean = clean_take(motion)
    n = clean.motion.n_frames
    fps = clean.motion.fps
    scorer = Evaluator(clean.motion)
    unwrapped = _unwrapped(clean.motion)
    known: dict[bytes, float] = {}

    def error(keys: np.ndarray) -> float:  # E of the clean take rebuilt from `keys`
        if keys.tobytes() not in known:
            rebuilt = reconstruct(clean.motion, keys, unwrapped=unwrapped)
            known[keys.tobytes()] = scorer.error_e(rebuilt)
        return known[keys.tobytes()]

    name = motion.name
    built: dict[str, Case] = {}
    rows: list[dict[str, object]] = []
    for mode in modes:
        t0 = _time.perf_counter()
        base = _keys(mode, clean.motion, methods)
        base_e = {m: error(_rows_of(k.astype(np.float64), n)) for m, k in base.items()}
        if progress:
            progress(f"{name} {mode} clean: {_time.perf_counter() - t0:.1f} s")
        for case_name in cases:
            if case_name not in built:
                built[case_name] = build_case(motion, case_name, seed)
            case = built[case_name]
            if case.online_only and mode != "online":
                continue
            t0 = _time.perf_counter()
            found = _keys(mode, case.variant.motion, methods, case.stream)
            seconds = _time.perf_counter() - t0
            for m in methods:
                mapped = keys_in_take(case.variant, found[m])
                keys = _rows_of(mapped, n)
                e = error(keys)
                rows.append({
                    "clip": name, "method": m, "mode": mode, "variant": case_name,
                    "clean_keys": int(len(base[m])), "keys": int(len(mapped)),
                    "f1": float(f1_against(base[m], mapped, fps)),
                    "key_ratio": _ratio(len(mapped), len(base[m])),
                    "e_clean": float(base_e[m]), "e_variant": float(e),
                    "e_ratio": _ratio(e, base_e[m]),
                    "identical": bool(np.array_equal(keys, _rows_of(
                        base[m].astype(np.float64), n))),
                    "seconds": seconds})
            if progress:
                progress(f"{name} {mode} {case_name}: {seconds:.1f} s")
    return rows


def measure(motions: Iterable[Motion], methods: Sequence[str] = METHODS,
            modes: Sequence[str] = MODES, cases: Sequence[str] = CASES,
            progress: Callable[[str], None] | None = None) -> list[dict[str, object]]:
    """`measure_clip` over several clips, rows concatenated."""
    rows: list[dict[str, object]] = []
    for motion in motions:
        rows += measure_clip(motion, methods, modes, cases, progress)
    return rows


def _group(rows: Iterable[Mapping[str, object]]) -> dict[tuple[str, str, str],
                                                           list[Mapping[str, object]]]:
    groups: dict[tuple[str, str, str], list[Mapping[str, object]]] = {}
    for r in rows:
        groups.setdefault((str(r["method"]), str(r["mode"]), str(r["variant"])), []).append(r)
    return groups


def _floats(rows: Sequence[Mapping[str, object]], key: str) -> np.ndarray:
    return np.array([float(r[key]) for r in rows])  # type: ignore[arg-type]


def summarise(rows: Iterable[Mapping[str, object]]) -> list[dict[str, object]]:
    """Per (method, mode, variant) over the clips: mean and worst F1 (and its clip), key
    ratio range, worst E ratio (and its clip), share of clips whose keys are the clean keys."""
    out: list[dict[str, object]] = []
    for (method, mode, variant), group in _group(rows).items():
        f1, ratio, e = _floats(group, "f1"), _floats(group, "key_ratio"), _floats(
            group, "e_ratio")
        out.append({"method": method, "mode": mode, "variant": variant, "clips": len(group),
                    "f1_mean": float(f1.mean()), "f1_worst": float(f1.min()),
                    "f1_worst_clip": str(group[int(f1.argmin())]["clip"]),
                    "ratio_min": float(ratio.min()), "ratio_max": float(ratio.max()),
                    "e_ratio_worst": float(e.max()),
                    "e_ratio_worst_clip": str(group[int(e.argmax())]["clip"]),
                    "identical": float(np.mean([bool(r["identical"]) for r in group]))})
    order = {m: i for i, m in enumerate(METHODS)}
    cases = {c: i for i, c in enumerate(CASES)}
    out.sort(key=lambda s: (order.get(str(s["method"]), 99), MODES.index(str(s["mode"])),
                            cases.get(str(s["variant"]), 99)))
    return out


def acceptance(rows: Iterable[Mapping[str, object]], goals: Goals = GOALS
               ) -> dict[tuple[str, str, str, str], tuple[bool, str]]:
    """The invariance goal cell by cell: (method, mode, variant, check) -> (met, measured),
    check one of "f1" (mean and worst), "count" (every clip's key ratio in the band),
    "e" (every clip's E ratio under the ceiling); standard variants only."""
    cells: dict[tuple[str, str, str, str], tuple[bool, str]] = {}
    for (method, mode, variant), group in _group(rows).items():
        if variant not in STANDARD:
            continue
        ratio = _floats(group, "key_ratio")
        ok = bool(np.all((ratio >= goals.ratio_low) & (ratio <= goals.ratio_high)))
        cells[(method, mode, variant, "count")] = (
            ok, f"key ratio {ratio.min():.2f}-{ratio.max():.2f}")
        if method in goals.f1_methods:
            f1 = _floats(group, "f1")
            ok = bool(f1.mean() >= goals.f1_mean and f1.min() >= goals.f1_worst)
            cells[(method, mode, variant, "f1")] = (
                ok, f"F1 mean {f1.mean():.3f}, worst {f1.min():.3f}")
        if method in goals.e_methods:
            e = _floats(group, "e_ratio")
            cells[(method, mode, variant, "e")] = (bool(e.max() <= goals.e_ratio),
                                                   f"E ratio worst {e.max():.3f}")
    return cells
