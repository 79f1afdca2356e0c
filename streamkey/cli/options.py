"""Method options generated from `streamkey.methods.params`, and their checks.

`add_method_options` makes one argument group per method from the declared parameters;
`method_params` turns the parsed options into the per-method keyword arguments of the library
(`params[method]`, and `params["*"]` for what every method shares), refusing an option of a
method not chosen and an online-only option offline.
"""

from __future__ import annotations

import argparse
import functools
import sys
from collections.abc import Callable
from typing import Any

from ..errors import UsageError
from ..units import Duration, parse_duration

__all__ = ["add_method_options", "add_playable_options", "add_roles_option",
           "add_dashboard_options", "method_params", "online_params", "chosen_methods",
           "roles_of"]

DEFAULT_MAX_BRIDGE_FRAMES = 12  # streamkey.online.DEFAULT_MAX_BRIDGE_FRAMES (help text)


def _duration(text: str, integer: bool) -> int | float | Duration:
    """A duration option: a plain frame count stays the number the methods took before
    (int or float), seconds (`0.5s`, `500ms`) become a `Duration`, converted at the stream's
    rate by the library."""
    try:
        return int(text) if integer else float(text)
    except ValueError:
        pass
    try:
        d = parse_duration(text)
    except UsageError:
        raise ValueError(text) from None
    if d.unit == "s":
        return d
    return int(d.value) if integer else d.value


def _converter(param: Any) -> Callable[[str], Any]:
    """The argparse `type` of a declared parameter."""
    if param.kind == "duration":
        def duration(text: str) -> int | float | Duration:
            try:
                return _duration(text, param.integer)
            except ValueError:
                raise argparse.ArgumentTypeError(
                    f"{text!r} is not frames or seconds with an s suffix (e.g. 0.5s)") from None
        return duration
    return int if param.integer else float


def add_method_options(p: argparse.ArgumentParser, online: bool | None) -> None:
    """The method parameters, one argument group per method, with units and defaults.
    `online`: True for `run` (online methods), None for `extract` (all; lookahead and gap
    bridging with --online), False for `sheet` / `plot` (offline only)."""
    from ..methods import ONLINE_METHODS
    from ..methods.params import METHOD_PARAMS, TITLES

    for method, declared in METHOD_PARAMS.items():
        if online is True and method not in ONLINE_METHODS:
            continue
        g = p.add_argument_group(f"{method} ({TITLES[method]})")
        for param in declared:
            if param.online_only and online is False:
                continue
            text = param.help.replace("%", "%%")
            if param.kind == "duration":
                text += " (or seconds: 0.5s)"
            if param.kind == "flag":
                g.add_argument(param.option, action="store_true", help=text)
            elif param.kind == "choice":
                g.add_argument(param.option, choices=param.choices, help=text,
                               default=param.default if param.always else None)
            else:
                g.add_argument(param.option, type=_converter(param), metavar=param.unit,
                               help=text)
    _add_shared_options(p, online)


def _add_shared_options(p: argparse.ArgumentParser, online: bool | None) -> None:
    from ..filters import DEFAULT_NOISE_CUTOFF_HZ
    from ..methods.params import SHARED_PARAMS

    g = p.add_argument_group(
        "every method", "VALUE applies to each chosen method it concerns; METHOD=VALUE,... "
        "sets methods one by one (e.g. --lookahead saliency=60,speed=90)")
    g.add_argument("--count", metavar="[METHOD=]N",
                   help="keyframe count for simplify, uniform, decimate, optimal (offline; "
                        "uniform and decimate default to the saliency count); online "
                        "methods refuse it")
    g.add_argument("--tolerance", metavar="[METHOD=]ERR",
                   help="simplify's or optimal's tolerance (units above); with both chosen, "
                        "name them")
    if online is False:
        return
    where = "" if online else "with --online: "
    for param, _ in SHARED_PARAMS:
        g.add_argument(param.option, metavar=f"[METHOD=]{param.unit}",
                       help=f"{where}{param.help}; frames, or seconds: 0.5s")
        if param.name == "lookahead":
            g.add_argument("--max-gap", type=float, metavar="SECONDS",
                           help="insert a key (best frame by the optimal segment cost) in every "
                                "stretch longer than SECONDS without one")
    g.add_argument("--noise-cutoff", type=float, metavar="HZ",
                   help="the sensor-noise low-pass before the features (zero-phase Gaussian, "
                        "50 %% gain at HZ), offline and online alike; online it adds about "
                        "0.55/HZ s to every latency (default "
                        f"{DEFAULT_NOISE_CUTOFF_HZ:g}; 0: off)")
    g.add_argument("--max-bridge", metavar="FRAMES|SECONDSs",
                   help=f"{where}interpolate over at most this many missing frames (or "
                        f"seconds: 0.1s); a longer gap restarts the windows (default "
                        f"{DEFAULT_MAX_BRIDGE_FRAMES} frames)")


def add_playable_options(p: argparse.ArgumentParser, live: bool = True) -> None:
    """`--min-interval` (and, live, `--provisional`, `--signal [N]`)."""
    p.add_argument("--min-interval", metavar="SECONDS",
                   help="any method: of keys closer than SECONDS keep the stronger; one "
                        "value or METHOD=SECONDS,... (online: adds SECONDS to the latency)")
    if live:
        p.add_argument("--provisional", action="store_true",
                       help="also send a provisional event as soon as a method sees a likely "
                            "key, then exactly one confirm (the keyframe event) or cancel")
        p.add_argument("--signal", type=int, nargs="?", const=1, metavar="N",
                       help="send a signal event (body speed, each method's keyness) every "
                            "N frames (default 1: every frame)")


def add_roles_option(p: argparse.ArgumentParser) -> None:
    """`--roles FILE`."""
    p.add_argument("--roles", metavar="FILE",
                   help="JSON {role: joint name} for skeletons the built-in tables (CMU, "
                        "Mixamo, Axis, Rokoko, Xsens, Unity/VMC) do not name")


def add_dashboard_options(p: argparse.ArgumentParser) -> None:
    """`--dashboard [PORT]` and `--log PATH`."""
    p.add_argument("--dashboard", type=int, nargs="?", const=8765, metavar="PORT",
                   help="serve the live page on http://127.0.0.1:PORT/ (default port 8765; "
                        "0 picks a free one)")
    p.add_argument("--log", metavar="PATH",
                   help="dashboard: JSON Lines session log for events and annotations "
                        "(default: the jsonl: sink, else session-<UTC time>.jsonl)")


def chosen_methods(args: argparse.Namespace, online: bool) -> list[str]:
    """The method names of `--method` (every online one for commands without it)."""
    from ..methods import ONLINE_METHODS, parse_methods

    text = getattr(args, "method", None)
    return parse_methods(text, online=online) if text else list(ONLINE_METHODS)


def _per_method(args: argparse.Namespace, flag: str, parse: Callable[[str], Any], unit: str,
                methods: list[str], applies: tuple[str, ...]) -> dict[str, Any]:
    """`--flag VALUE` (every chosen method in `applies`) or `--flag METHOD=VALUE,...`, checked:
    {method: value}. A bad name or value is one usage error."""
    text = getattr(args, flag.lstrip("-").replace("-", "_"), None)
    if text is None:
        return {}
    out: dict[str, Any] = {}
    for item in str(text).split(","):
        name, sep, value = item.strip().rpartition("=")
        name = name.strip()
        if sep and name not in applies:
            raise UsageError(f"{flag}: {name!r} is not a method that takes it; name one of "
                             f"{', '.join(applies)}")
        if sep and name not in methods:
            raise UsageError(f"{flag}: {name} is not among the chosen methods "
                             f"({', '.join(methods)}); add it to --method or drop {item.strip()}")
        try:
            number = parse(value.strip())
        except ValueError:
            raise UsageError(f"{flag}: {value.strip()!r} is not {unit} (give VALUE or "
                             f"METHOD=VALUE,...)") from None
        targets = [name] if sep else [m for m in methods if m in applies]
        if not targets:
            raise UsageError(f"{flag}: none of the chosen methods ({', '.join(methods)}) takes "
                             f"it; it applies to {', '.join(applies)}")
        for m in targets:
            out[m] = number
    return out


def _max_bridge(text: str | None) -> dict[str, Any]:
    """`--max-bridge FRAMES` or `SECONDSs` as {"max_bridge_frames" | "max_bridge_seconds": v}."""
    if text is None:
        return {}
    try:
        d = parse_duration(text.lower())
    except UsageError:
        d = Duration.frames(-1)
    if not 0 <= d.value <= 1e6:
        raise UsageError(f"--max-bridge: {text!r} is not FRAMES (a whole number >= 0) or "
                         "SECONDS with an s suffix (e.g. 0.1s)")
    return {"max_bridge_seconds": d.value} if d.unit == "s" else {
        "max_bridge_frames": int(d.value)}


def _own_params(args: argparse.Namespace, methods: list[str], online: bool,
                params: dict[str, dict[str, Any]]) -> None:
    """Every method's own declared parameters from `args` into `params`, checked."""
    from ..methods.params import METHOD_PARAMS

    for method, declared in METHOD_PARAMS.items():
        for param in declared:
            value = getattr(args, param.dest, None)
            if param.always:
                for name in (method, *param.also):
                    params[name][param.name] = param.default if value is None else value
                continue
            if param.negate:
                params[method][param.name] = not value
            if value is None or value is False:
                continue
            if method not in methods:
                raise UsageError(f"{param.option} is a {method} option, and {method} is not "
                                 f"among the chosen methods ({', '.join(methods)}); add it to "
                                 "--method")
            if param.online_only and not online:
                raise UsageError(f"{param.option}: online only; add --online")
            params[method][param.name] = not value if param.negate else value


def _shared_params(args: argparse.Namespace, methods: list[str], online: bool,
                   params: dict[str, dict[str, Any]]) -> None:
    """`--history`, `--hop`, `--lookahead`, `--tolerance`, `--count` into `params`, checked."""
    from ..methods import COUNTED_METHODS
    from ..methods.params import SHARED_PARAMS

    unit = "a whole number of frames or seconds with an s suffix"
    for param, applies in SHARED_PARAMS:
        parse = functools.partial(_duration, integer=param.integer)
        chosen = _per_method(args, param.option, parse, unit, methods,
                             applies if online else tuple(methods))
        if chosen and not online:
            raise UsageError(f"{param.option}: online only; add --online")
        for name, value in chosen.items():
            params[name][param.name] = value
    tol = _per_method(args, "--tolerance", float, "a number", methods, ("simplify", "optimal"))
    if getattr(args, "tolerance", None) is not None and "=" not in args.tolerance and len(tol) > 1:
        raise UsageError("--tolerance is ambiguous with both simplify (body heights) and "
                         "optimal (body heights^2) chosen: use --simplify-tolerance and "
                         "--optimal-tolerance, or --tolerance simplify=V,optimal=W")
    for name, value in tol.items():
        if "tolerance" in params[name]:
            raise UsageError(f"--tolerance and --{name}-tolerance both set the {name} "
                             "tolerance; give one")
        params[name]["tolerance"] = value
    counts = _per_method(args, "--count", int, "a whole number", methods, COUNTED_METHODS)
    for name, value in counts.items():
        params[name]["count"] = value


def _playable_params(args: argparse.Namespace) -> dict[str, Any]:
    """`--min-interval`, `--provisional`, `--signal`, for `params["*"]`."""
    from ..playable import parse_min_interval

    signal = getattr(args, "signal", None)
    if signal is not None and signal < 1:
        raise UsageError(f"--signal: N must be >= 1 frame, got {signal}")
    return {"min_interval": parse_min_interval(getattr(args, "min_interval", None)),
            "provisional": bool(getattr(args, "provisional", False)), "signal": signal or 0}


def method_params(args: argparse.Namespace, online: bool = False) -> dict[str, dict[str, Any]]:
    """Per-method keyword arguments from the method options (only those given, plus the
    always-set ones); `"*"` holds `max_gap`, `min_interval` and the gap bridging for every
    method. An option of a method not chosen, or an online-only one offline, is a usage
    error."""
    from ..methods import OFFLINE_METHODS

    methods = chosen_methods(args, online)
    params: dict[str, dict[str, Any]] = {name: {} for name in OFFLINE_METHODS}
    _own_params(args, methods, online, params)
    _shared_params(args, methods, online, params)
    if getattr(args, "verbose", False):
        params["isodata"].update(verbose=True, log=lambda line: print(line, file=sys.stderr))
    bridge = _max_bridge(getattr(args, "max_bridge", None))
    if bridge and not online:
        raise UsageError("--max-bridge: online only; add --online")
    params["*"] = {"max_gap": getattr(args, "max_gap", None), **bridge,
                   "noise_cutoff_hz": _noise_cutoff(getattr(args, "noise_cutoff", None)),
                   **_playable_params(args)}
    return params


def _noise_cutoff(hz: float | None) -> float | None:
    """`--noise-cutoff HZ`: the front end's cut-off; not given: the library default; 0: off
    (None)."""
    from ..filters import DEFAULT_NOISE_CUTOFF_HZ

    if hz is None:
        return DEFAULT_NOISE_CUTOFF_HZ
    if not (0 <= hz < 1e4):
        raise UsageError(f"--noise-cutoff: a positive number of Hz, or 0 to turn the noise "
                         f"filter off, got {hz:g}")
    return float(hz) if hz > 0 else None


def roles_of(args: argparse.Namespace) -> dict[str, str] | None:
    """`--roles FILE`: the role mapping, or None (built-in tables)."""
    from ..roles import load_role_mapping

    path = getattr(args, "roles", None)
    return load_role_mapping(path) if path else None


def online_params(args: argparse.Namespace) -> dict[str, dict[str, Any]]:
    """`method_params` plus the `--roles` mapping for the online keyframers (wire skeletons)."""
    from ..methods import ONLINE_METHODS

    params = method_params(args, online=True)
    roles = roles_of(args)
    if roles:
        for name in ONLINE_METHODS:
            params[name] = {**params.get(name, {}), "role_mapping": roles}
    return params
