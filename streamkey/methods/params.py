"""The tunable parameters of every method, declared once as data.

Each `Param` names a keyword argument of a method's offline `extract` and/or online keyframer,
with its unit, default, a one-line help and whether only the online keyframer takes it. The
command line builds its options and its checks (an option of a method not chosen, an
online-only option offline) from these tuples; the library converts `Duration` values to the
frame counts the methods take (`to_method_units`), where the capture rate is known.

Pure data and arithmetic: importing this module imports no method (and so no compiler).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

from ..units import Duration, frames_of, whole_frames

__all__ = ["Param", "Kind", "METHOD_PARAMS", "SHARED_PARAMS", "TITLES", "SALIENCY", "SPEED",
           "SIMPLIFY", "OPTIMAL", "ISODATA", "CURVEFIT", "to_method_units", "params_of"]

Kind = Literal["duration", "number", "flag", "choice"]


@dataclass(frozen=True, slots=True)
class Param:
    """One tunable parameter of a method.

    `name` is the keyword argument; `flag` the command-line option when it is not
    `--name-with-dashes`. A `duration` takes frames or seconds (`0.5s`) and reaches the method
    as frames (whole frames when `integer`); a `number` is a plain value in `unit`; a `flag`
    is a switch (`negate`: the switch sets the parameter to False); a `choice` one of
    `choices`. `online_only`: only the online keyframer takes it. `always`: the value (its
    default included) is passed to `also` methods too, whichever methods are chosen.
    """

    name: str
    kind: Kind
    help: str
    unit: str | None = None
    default: Any = None
    integer: bool = False
    online_only: bool = False
    flag: str | None = None
    choices: tuple[str, ...] = ()
    negate: bool = False
    always: bool = False
    also: tuple[str, ...] = ()

    @property
    def option(self) -> str:
        """The command-line option, e.g. `--update-every`."""
        return self.flag or "--" + self.name.replace("_", "-")

    @property
    def dest(self) -> str:
        """The attribute of the parsed options, e.g. `update_every`."""
        return self.option[2:].replace("-", "_")


SALIENCY = (
    Param("preset", "choice", "default auto: high (sigma 3, k 10) if the body's 90th-percentile "
          "speed over the first 1 s of motion is >= 1.03 body heights/s, else low (sigma 10, "
          "k 7); online decides after that second too", choices=("auto", "low", "high"),
          default="auto"),
    Param("sigma", "duration", "base scale (default: the preset's, 1/12 s or 1/40 s; "
          "frames if a plain number)", unit="FRAMES"),
    Param("k", "number", "PCA curves (default: the preset's)", unit="N", integer=True),
    Param("contact", "flag", "no foot-contact curves (default: the ankle heights replace the "
          "last two curves)", flag="--no-contact", negate=True, default=True),
    Param("variance_rule", "flag", "k = at least the curves reaching 90 % of the variance",
          default=False),
    Param("update_every", "duration", "online: recompute the PCA basis at least this often "
          "(default 10 s)", unit="FRAMES", default=Duration.seconds(10.0), integer=True,
          online_only=True),
)
SPEED = (
    Param("f_c", "number", "low-pass cut-off of the joint speeds (default 10 Hz)", unit="HZ",
          default=10.0),
    Param("f_max", "number", "finest scale (default 8 Hz)", unit="HZ", default=8.0),
    Param("f_min", "number", "coarsest scale (default 0.2 Hz)", unit="HZ", default=0.2),
    Param("r", "number", "ratio of successive scales (default 0.95)", unit="R", default=0.95,
          flag="--scale-ratio"),
    Param("cut", "choice", "keypose cut: quantile (default: U above 0.4 x the 95th "
          "percentile of the candidates' intensities) or mojena (Miura's Ward + Mojena cut)",
          choices=("quantile", "mojena"), default="quantile"),
    Param("mojena_k", "number", "with --cut mojena: Mojena constant of the Ward cut-off, "
          "larger: fewer keys (default 2.75)", unit="K", default=2.75),
    Param("cutoff_history", "duration", "online: how far back candidates feed the cut-off "
          "(default 60 s)", unit="FRAMES", default=Duration.seconds(60.0), integer=True,
          online_only=True),
    Param("warmup_candidates", "number", "online: candidates before the cut-off is trusted "
          "(default 20)", unit="N", default=20, integer=True, online_only=True),
    Param("segment_statistics", "flag", "online: calibration holds and still stretches stay "
          "out of the cut-off sample (default: in; the segment detector reads calm motion as "
          "still)", default=False, online_only=True),
)
SIMPLIFY = (
    Param("tolerance", "number", "largest RMS joint error of the straight line between keys: "
          "body heights with --space positions (default 0.03), degrees with channels "
          "(default 40)", unit="ERR", flag="--simplify-tolerance"),
    Param("ratio", "number", "instead: largest error / chord length (Önder)"),
    Param("space", "choice", "simplify and decimate: body-frame joint positions in body "
          "heights (default) or channel values (rotations unwrapped)",
          choices=("positions", "channels"), default="positions", always=True,
          also=("decimate",)),
    Param("merge", "duration", "online: a key this close after the last committed one is "
          "taken to be it (no near-duplicates; default 1/15 s)", unit="FRAMES",
          default=Duration.seconds(8 / 120), integer=True, online_only=True),
    Param("max_span", "duration", "online: longest open segment (default 8 x lookahead)",
          unit="FRAMES", integer=True, online_only=True),
)
OPTIMAL = (
    Param("rate", "number", "keys per second of motion (calibration holds and still "
          "stretches excluded; default 6)", unit="KEYS_PER_S", default=6.0),
    Param("tolerance", "number", "instead: largest mean per-frame error between keys (body "
          "heights^2)", unit="ERR", flag="--optimal-tolerance"),
    Param("lam", "number", "instead: fixed cost per key (frames x body heights^2)",
          unit="PENALTY"),
    Param("max_segment", "number", "longest stretch between keys (default 2 s)",
          unit="SECONDS", default=2.0),
    Param("root_translation", "flag", "include the root's path in the error (default: body "
          "frame only)", default=False),
    Param("hold_keys", "flag", "rate mode: keys allowed inside calibration holds (default: "
          "none strictly inside)", default=False),
)
ISODATA = (
    Param("cluster_seconds", "number", "expected cluster duration, smaller: more keys "
          "(default 0.208 s)", unit="SECONDS"),
    Param("max_merges", "number", "most class merges per iteration (default: unlimited)",
          unit="N", integer=True),
    Param("outlier_fence", "number", "distances beyond Q3 + IQR x this (pose glitches) stay "
          "out of the two-class cut (default 10)", unit="IQR", default=10.0),
)
CURVEFIT = (
    Param("smooth", "number", "smoothing weight, smaller: more keys (default 4)", unit="S",
          default=4.0),
    Param("key_cost", "number", "cost per key, smaller: more keys (default 1)", unit="C",
          default=1.0),
    Param("tol", "number", "a channel stops when a pass lowers its cost by less than this "
          "fraction (default 0.001)", unit="TOL", default=1e-3, flag="--curvefit-tol"),
    Param("max_passes", "number", "most refinement passes (default 100)", unit="N",
          default=100, integer=True),
)

# Every method's own parameters; uniform and decimate have none of their own (--space,
# --count are shared).
METHOD_PARAMS: Mapping[str, tuple[Param, ...]] = {
    "saliency": SALIENCY, "speed": SPEED, "simplify": SIMPLIFY, "optimal": OPTIMAL,
    "isodata": ISODATA, "curvefit": CURVEFIT,
}
# What each method is, for the command line's option groups.
TITLES: Mapping[str, str] = {
    "saliency": "multiscale motion saliency, Halit & Capin", "speed": "speed minima, Miura",
    "simplify": "curve simplification", "optimal": "penalised dynamic programming",
    "isodata": "clustering, Zhang et al.", "curvefit": "per-channel Hermite keys, Önder",
}
# Online parameters several methods take, set for all of them or `METHOD=VALUE` one by one:
# (parameter, the methods that take it).
SHARED_PARAMS: tuple[tuple[Param, tuple[str, ...]], ...] = (
    (Param("lookahead", "duration", "how long a decision may wait (default: the method's, "
           "saliency 2 x 2.5 sigma + 2 sigma + 1 frame (121 frames at 120 Hz, 37 with --preset "
           "high), speed 1 s, simplify 0.5 s, optimal 1 s)",
           unit="FRAMES", integer=True, online_only=True),
     ("saliency", "speed", "simplify", "optimal")),
    (Param("history", "duration", "past motion kept: saliency (default 10 s), speed (20 s), "
           "simplify (4 x lookahead)", unit="FRAMES", integer=True, online_only=True),
     ("saliency", "speed", "simplify")),
    (Param("hop", "duration", "time between re-analyses: speed (default lookahead / 5, "
           "at most 0.2 s), simplify (1/15 s)", unit="FRAMES", integer=True, online_only=True),
     ("speed", "simplify")),
)


def params_of(method: str) -> tuple[Param, ...]:
    """Every parameter `method` takes: its own and the shared ones that apply to it."""
    return METHOD_PARAMS.get(method, ()) + tuple(p for p, takers in SHARED_PARAMS
                                                 if method in takers)


def to_method_units(method: str, kwargs: Mapping[str, Any], fps: float) -> dict[str, Any]:
    """`kwargs` of `method` with every `Duration` converted to the frames the method takes
    at `fps` (whole frames for integer parameters); plain numbers pass unchanged, so a frame
    count gives exactly what it gave before durations had units."""
    durations = {p.name: p for p in params_of(method) if p.kind == "duration"}
    out = dict(kwargs)
    for name, value in kwargs.items():
        if isinstance(value, Duration):
            param = durations.get(name)
            out[name] = (whole_frames(value, fps) if param is None or param.integer
                         else frames_of(value, fps))
    return out
