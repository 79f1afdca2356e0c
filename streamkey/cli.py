"""The `streamkey` command line: a thin layer over the library (DESIGN §7).

Every input error becomes one `error: ...` line on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from . import __version__
from .errors import StreamkeyError
from .playable import add_playable_options, playable_params

__all__ = ["main", "build_parser"]


def _progress(quiet: bool):  # type: ignore[no-untyped-def]
    def report(i: int, n: int, path: Path) -> None:
        if not quiet and n > 1:
            print(f"[{i + 1}/{n}] {path.name}", file=sys.stderr, flush=True)
    return report


def _chosen(args: argparse.Namespace, online: bool) -> list[str]:
    """The method names of `--method` (every online one for commands without it)."""
    from .methods import ONLINE_METHODS, parse_methods

    text = getattr(args, "method", None)
    return parse_methods(text, online=online) if text else list(ONLINE_METHODS)


def _per_method(args: argparse.Namespace, flag: str, kind: type, methods: list[str],
                applies: tuple[str, ...]) -> dict[str, Any]:
    """`--flag VALUE` (every chosen method in `applies`) or `--flag METHOD=VALUE,...`, checked:
    {method: value}. A bad name or value is one usage error."""
    from .errors import UsageError

    text = getattr(args, flag.lstrip("-").replace("-", "_"), None)
    if text is None:
        return {}
    unit = "a whole number" if kind is int else "a number"
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
            number = kind(value.strip())
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
    from .errors import UsageError

    if text is None:
        return {}
    t = text.strip().lower()
    try:
        if t.endswith("s"):
            value: float = float(t[:-1])
            key = "max_bridge_seconds"
        else:
            value, key = int(t), "max_bridge_frames"
    except ValueError:
        value, key = -1, ""
    if not key or not 0 <= value <= 1e6:
        raise UsageError(f"--max-bridge: {text!r} is not FRAMES (a whole number >= 0) or "
                         "SECONDS with an s suffix (e.g. 0.1s)")
    return {key: value}


# (method, parameter, option dest, online only) of every method option; flag: --dest-with-dashes
_OPTIONS = [
    ("saliency", "sigma", "sigma", False), ("saliency", "k", "k", False),
    ("saliency", "preset", "preset", False), ("saliency", "variance_rule", "variance_rule", False),
    ("saliency", "update_every", "update_every", True),
    ("speed", "f_c", "f_c", False), ("speed", "f_max", "f_max", False),
    ("speed", "f_min", "f_min", False), ("speed", "r", "scale_ratio", False),
    ("speed", "mojena_k", "mojena_k", False), ("speed", "cutoff_history", "cutoff_history", True),
    ("speed", "warmup_candidates", "warmup_candidates", True),
    ("simplify", "tolerance", "simplify_tolerance", False), ("simplify", "ratio", "ratio", False),
    ("simplify", "merge", "merge", True), ("simplify", "max_span", "max_span", True),
    ("optimal", "rate", "rate", False), ("optimal", "tolerance", "optimal_tolerance", False),
    ("optimal", "lam", "lam", False), ("optimal", "max_segment", "max_segment", False),
    ("optimal", "root_translation", "root_translation", False),
    ("isodata", "cluster_seconds", "cluster_seconds", False),
    ("isodata", "max_merges", "max_merges", False),
    ("isodata", "outlier_fence", "outlier_fence", False),
    ("curvefit", "smooth", "smooth", False), ("curvefit", "key_cost", "key_cost", False),
    ("curvefit", "tol", "curvefit_tol", False), ("curvefit", "max_passes", "max_passes", False),
]


def _method_params(args: argparse.Namespace, online: bool = False) -> dict[str, dict[str, Any]]:
    """Per-method keyword arguments from the method options (only those given, plus the
    always-set ones); `"*"` holds `max_gap` and the gap bridging for every online keyframer.
    An option of a method not chosen, or an online-only one offline, is a usage error."""
    from .errors import UsageError
    from .methods import COUNTED_METHODS, OFFLINE_METHODS, ONLINE_METHODS

    methods = _chosen(args, online)
    space = getattr(args, "space", "positions")
    no_contact = getattr(args, "no_contact", False)
    params: dict[str, dict[str, Any]] = {name: {} for name in OFFLINE_METHODS}
    params["saliency"]["contact"] = not no_contact
    params["simplify"]["space"] = params["decimate"]["space"] = space
    for method, key, dest, live in (*_OPTIONS, ("saliency", "contact", "no_contact", False)):
        value = getattr(args, dest, None)
        if value is None or value is False:
            continue
        flag = "--" + dest.replace("_", "-")
        if method not in methods:
            raise UsageError(f"{flag} is a {method} option, and {method} is not among the "
                             f"chosen methods ({', '.join(methods)}); add it to --method")
        if live and not online:
            raise UsageError(f"{flag}: online only; add --online")
        params[method][key] = not value if key == "contact" else value
    for flag, applies in (("--history", ("saliency", "speed", "simplify")),
                          ("--hop", ("speed", "simplify")),
                          ("--lookahead", tuple(ONLINE_METHODS))):
        chosen = _per_method(args, flag, int, methods, applies if online else tuple(methods))
        if chosen and not online:
            raise UsageError(f"{flag}: online only; add --online")
        for name, value in chosen.items():
            params[name][flag[2:]] = value
    tol = _per_method(args, "--tolerance", float, methods, ("simplify", "optimal"))
    if getattr(args, "tolerance", None) is not None and "=" not in args.tolerance and len(tol) > 1:
        raise UsageError("--tolerance is ambiguous with both simplify (body heights) and "
                         "optimal (body heights^2) chosen: use --simplify-tolerance and "
                         "--optimal-tolerance, or --tolerance simplify=V,optimal=W")
    for name, value in tol.items():
        if "tolerance" in params[name]:
            raise UsageError(f"--tolerance and --{name}-tolerance both set the {name} "
                             "tolerance; give one")
        params[name]["tolerance"] = value
    for name, value in _per_method(args, "--count", int, methods, COUNTED_METHODS).items():
        params[name]["count"] = value
    if getattr(args, "verbose", False):
        params["isodata"].update(verbose=True, log=lambda line: print(line, file=sys.stderr))
    bridge = _max_bridge(getattr(args, "max_bridge", None))
    if bridge and not online:
        raise UsageError("--max-bridge: online only; add --online")
    params["*"] = {"max_gap": getattr(args, "max_gap", None), **bridge,  # every online keyframer
                   **playable_params(args)}
    return params


def _write(text: str, output: str) -> None:
    # File names that are not UTF-8 come back out as the bytes they were (surrogateescape).
    data = text.encode("utf-8", "surrogateescape")
    if output != "-":
        Path(output).write_bytes(data)
    elif hasattr(sys.stdout, "buffer"):
        sys.stdout.flush()
        sys.stdout.buffer.write(data)
        sys.stdout.buffer.flush()
    else:  # a text-only stream (a StringIO in a caller's redirect)
        sys.stdout.write(data.decode("utf-8", "replace"))
        sys.stdout.flush()


def _roles(args: argparse.Namespace) -> dict[str, str] | None:
    """`--roles FILE`: the role mapping, or None (built-in tables)."""
    from .roles import load_role_mapping

    path = getattr(args, "roles", None)
    return load_role_mapping(path) if path else None


def _read(path: str, args: argparse.Namespace) -> Any:
    """A motion file, its skeleton carrying the `--roles` mapping."""
    from .batch import load_motion

    return load_motion(path, roles=_roles(args))


def _online_params(args: argparse.Namespace) -> dict[str, dict[str, Any]]:
    """`_method_params` plus the `--roles` mapping for the online keyframers (wire skeletons)."""
    from .methods import ONLINE_METHODS

    params = _method_params(args, online=True)
    roles = _roles(args)
    if roles:
        for name in ONLINE_METHODS:
            params[name] = {**params.get(name, {}), "role_mapping": roles}
    return params


def cmd_extract(args: argparse.Namespace) -> int:
    """`streamkey extract`: offline (or simulated online) keyframes of files and folders."""
    from .batch import extract_files, find_motion_files, results_csv, results_json
    from .methods import parse_methods

    paths = find_motion_files(args.paths)
    if args.engine != "local" or args.address:  # a cluster engine: same files, same JSON
        from .cluster.engines import extract_with_engine

        methods = parse_methods(args.method, online=args.online)
        if args.online:
            from .streaming import check_online_params

            check_online_params(methods, _method_params(args))
        results = extract_with_engine(paths, methods, _method_params(args), args.engine,
                                      args.address, args.workers, _progress(args.quiet),
                                      _roles(args), args.online, args.lookahead)
    elif args.online:
        from .streaming import check_online_params, extract_files_online

        methods = parse_methods(args.method, online=True)
        params = _method_params(args, online=True)
        check_online_params(methods, params)
        results = list(extract_files_online(paths, methods, params, None, _progress(args.quiet),
                                            roles=_roles(args)))
    else:
        methods = parse_methods(args.method)
        results = list(extract_files(paths, methods, _method_params(args), _progress(args.quiet),
                                     roles=_roles(args)))
    if args.max_gap is not None and not args.online:
        from .methods.optimal import max_gap

        for r in results:
            if r.motion is not None:
                r.results = {m: max_gap(r.motion, k, args.max_gap)
                             for m, k in r.results.items()}
    if not args.online:  # online, the keyframers debounce themselves
        from .playable import debounce_results

        debounce_results(results, args.min_interval)
    _write(results_json(results) if args.format == "json" else results_csv(results), args.output)
    _export(results, args)
    failed = [r for r in results if r.error]
    for r in failed:
        print(f"error: {r.error}", file=sys.stderr)
    return 2 if failed else 0


def _export(results: list[Any], args: argparse.Namespace) -> None:
    """`extract --export-bvh / --export-reconstructed`: keyframes back out as BVH."""
    from .export import export_results

    for pattern, rebuilt in ((args.export_bvh, False), (args.export_reconstructed, True)):
        if pattern:
            for path in export_results(results, pattern, reconstructed=rebuilt):
                print(f"wrote {path}", file=sys.stderr)


def _dashboard(args: argparse.Namespace, source: Any, methods: list[str], to: list[str],
               rate: float | None, loop: bool = False, stream: str = "default") -> int:
    """`--dashboard [PORT]`: the engine with the live page; annotations into the session log."""
    import asyncio
    import json

    from .dashboard import check_port, default_log, run_dashboard

    port = check_port(args.dashboard)
    log = args.log or (None if any(a.startswith("jsonl:") for a in to) else default_log())
    summary, board = asyncio.run(run_dashboard(
        source, methods, to, _online_params(args), None,
        args.listen, stream, rate=rate, port=port, log=log, loop=loop,
        idle_exit=getattr(args, "idle_exit", None)))
    print(summary.text(), file=sys.stderr)
    print(f"annotations: {board.annotator.count}", file=sys.stderr)
    if getattr(args, "summary", None):
        Path(args.summary).write_text(json.dumps(summary.as_dict(), indent=1) + "\n")
    if summary.source_error:
        print(f"error: {getattr(args, 'source', 'source')}: {summary.source_error}",
              file=sys.stderr)
        return 2
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    """`streamkey demo`: the embedded demo motion through the keyframers, events printed."""
    from .demo import run_demo

    if args.dashboard is not None:
        from .methods import ONLINE_METHODS
        from .replay.demo import demo_motion

        return _dashboard(args, demo_motion(args.seconds), list(ONLINE_METHODS), [],
                          0.0 if args.fast else None, loop=True, stream="demo")

    return run_demo(seconds=args.seconds, offline=args.offline, fast=args.fast, out=sys.stdout)


def cmd_replay(args: argparse.Namespace) -> int:
    """`streamkey replay`: a recorded file as a paced frame stream."""
    from .amc import bvh_equivalent
    from .batch import load_motion
    from .errors import UsageError
    from .live import replay

    for name, low, high in (("--rate", 0.1, 1e5), ("--speed", 1e-3, 1e6)):
        value = getattr(args, name[2:])
        if value is not None and not low <= value <= high:
            raise UsageError(f"replay {name} must lie in {low:g}..{high:g}, got {value:g}")
    if args.frames is not None and args.frames < 0 or not 0 <= args.wait <= 3600:
        raise UsageError("replay --frames must be >= 0 and --wait in 0..3600 seconds")
    motion = bvh_equivalent(load_motion(args.file))
    if (args.rate or motion.fps) * args.speed < 0.1:
        raise UsageError(f"replay: {(args.rate or motion.fps) * args.speed:g} frames/s is too"
                         " slow (at least 0.1 frames/s; give --rate or --speed)")
    result = replay(motion, args.to, rate=args.rate, speed=args.speed, loop=args.loop,
                    start=args.start, end=args.end, listen=args.listen,
                    wait_subscribers=args.wait, count=args.frames, stream=args.stream)
    print(f"sent {result['frames']} frames", file=sys.stderr)
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    """`streamkey run`: live keyframes from a source to sinks until the source ends or Ctrl-C."""
    import asyncio
    import json

    from .adapters import make_source, parse_address
    from .adapters.osc import with_layout
    from .amc import bvh_equivalent, read_motion
    from .live import run_live
    from .methods import parse_methods
    from .streaming import check_online_params

    args.to = with_layout(args.to or [], args.osc_layout) or None
    methods = parse_methods(args.method, online=True)
    # Frames on the wire come from `replay`, which sends AMC clips as their BVH equivalent.
    skeleton_motion = bvh_equivalent(read_motion(args.skeleton)) if args.skeleton else None
    if skeleton_motion is not None:
        skeleton_motion.skeleton.roles = _roles(args) or skeleton_motion.skeleton.roles
    check_online_params(methods, _online_params(args))
    source: Any
    if Path(args.source).suffix.lower() in (".bvh", ".amc"):
        source = _read(args.source, args)  # fully read and checked before the engine starts
        _check_keyframers(source, methods, args)
    else:
        source = make_source(parse_address(args.source), args.listen,
                             skeleton_motion.skeleton if skeleton_motion else None,
                             skeleton_motion.fps if skeleton_motion else None)
    if args.realtime:
        from .live import raise_priority

        print(f"priority: {raise_priority()}", file=sys.stderr, flush=True)
    if args.dashboard is not None:
        return _dashboard(args, source, methods, args.to or [], 0.0 if args.fast else None,
                          stream=args.stream)
    _check_streams(args)
    summary = asyncio.run(run_live(source, methods, args.to or ["-"], _online_params(args),
                                   None, args.listen, args.stream,
                                   rate=0.0 if args.fast else None,
                                   idle_exit=args.idle_exit,
                                   reset_on_gap=args.reset_on_gap, max_streams=args.max_streams,
                                   stream_idle=args.stream_idle))
    print(summary.text(), file=sys.stderr)
    if args.summary:
        Path(args.summary).write_text(json.dumps(summary.as_dict(), indent=1) + "\n")
    if summary.source_error:  # the source died: say so and fail, never idle on
        print(f"error: {args.source}: {summary.source_error}", file=sys.stderr)
        return 2
    return 0


def cmd_cluster(args: argparse.Namespace) -> int:
    """`streamkey cluster run`: many streams on Ray shard actors (streamkey/cluster/)."""
    from .cluster.command import cmd_cluster_run

    return cmd_cluster_run(args, _online_params(args), _roles(args))


def _check_streams(args: argparse.Namespace) -> None:
    """`run --max-streams / --stream-idle` in range, or a usage error."""
    from .errors import UsageError

    if not 1 <= args.max_streams <= 10_000:
        raise UsageError(f"run --max-streams must lie in 1..10000, got {args.max_streams}")
    if args.stream_idle is not None and not 0.01 <= args.stream_idle <= 86_400:
        raise UsageError(f"run --stream-idle must lie in 0.01..86400 seconds, got "
                         f"{args.stream_idle:g}")


def _check_keyframers(motion: Any, methods: list[str], args: argparse.Namespace) -> None:
    """The keyframers can be built on this file's skeleton (roles, parameters), or its error."""
    from .batch import naming
    from .streaming import make_keyframers

    with naming(args.source):
        make_keyframers(motion, methods, _online_params(args))


def cmd_eval(args: argparse.Namespace) -> int:
    """`streamkey eval`: the thesis-style tables (Markdown + CSV) for every clip of a folder."""
    from .batch import find_motion_files
    from .tables import evaluate_files

    paths = find_motion_files([args.folder])
    out = Path(args.output)
    errors: list[str] = []
    written = evaluate_files(paths, out, progress=_progress(args.quiet), errors=errors)
    for p in written:
        print(f"wrote {p}")
    for line in errors:
        print(f"error: {line}", file=sys.stderr)
    return 2 if errors else 0


def cmd_bench(args: argparse.Namespace) -> int:
    """`streamkey bench`: time and memory of the offline and/or online methods, to files."""
    from .bench import BenchInterrupted, run_bench

    if args.robustness:
        from .bench_robustness import main as bench_robustness

        return bench_robustness(args)
    if args.playable:
        from .bench_playable import bench_playable

        for path in bench_playable(Path(args.data or "../shared/data/cmu"), Path(args.output)):
            print(f"wrote {path}")
        return 0
    kinds = [k for k in ("offline", "online", "agreement", "perf") if getattr(args, k)]
    kinds += [k for k in ("memory", "latency", "ws_clients") if getattr(args, k)]
    kinds += ["streams"] if getattr(args, "streams", False) else []
    if getattr(args, "engines", False):  # extract on local / Ray / Dask (issue 14 §6)
        from .cluster.bench import bench_engines

        for path in bench_engines(Path(args.data or "../shared/data/cmu"), Path(args.output)):
            print(f"wrote {path}")
        if not kinds:
            return 0
    kinds = kinds or ["offline", "online"]
    try:
        written = run_bench(kinds, Path(args.output), frames=args.frames, data=args.data,
                            quick=args.quick, say=lambda line: print(line, file=sys.stderr,
                                                                     flush=True))
    except BenchInterrupted as stop:
        for path in stop.written:
            print(f"wrote {path}")
        print("interrupted: the results above are what was measured before Ctrl-C "
              "(partial ones are marked \"partial\": true)", file=sys.stderr)
        return 130
    for path in written:
        print(f"wrote {path}")
    return 0


def _keyframes_of(path: str, method: str, args: argparse.Namespace) -> tuple[Any, Any]:
    from .batch import extract_motion, naming
    from .methods import parse_methods

    names = parse_methods(method)
    motion = _read(path, args)
    with naming(path):
        return motion, extract_motion(motion, names, _method_params(args))


def cmd_sheet(args: argparse.Namespace) -> int:
    """`streamkey sheet`: the keyposes of one clip as a contact sheet of stick figures."""
    from .errors import InputError, UsageError
    from .inputs import display_name
    from .methods import parse_methods
    from .sheet import contact_sheet

    names = parse_methods(args.method)
    if len(names) != 1:
        raise UsageError("sheet: choose one method (--method saliency, speed, ...)")
    motion, results = _keyframes_of(args.file, args.method, args)
    keys = results[names[0]]
    if len(keys) == 0:
        raise InputError(f"{args.file}: {names[0]} finds no keypose to draw in this clip")
    if args.per_page < 0:
        raise UsageError(f"sheet --per-page must be >= 0 (0: one page), got {args.per_page}")
    sheet = contact_sheet(motion, keys, args.output, columns=args.columns, view=args.view,
                          title=f"{display_name(motion.name)}: {len(keys)} {names[0]} keyposes",
                          per_page=args.per_page or None)
    for page in sheet.pages:
        print(f"wrote {page}", file=sys.stderr)
    print(f"{sheet.figures} keyposes on {len(sheet.pages)} page(s): {sheet.frames}",
          file=sys.stderr)
    return 0


def cmd_plot(args: argparse.Namespace) -> int:
    """`streamkey plot`: a clip's driving signals with the keyframes of each method marked."""
    from .sheet import plot_signals

    motion, results = _keyframes_of(args.file, args.method, args)
    print(f"wrote {plot_signals(motion, results, args.output)}", file=sys.stderr)
    return 0


def _add_method_options(p: argparse.ArgumentParser, online: bool | None) -> None:
    """The method parameters, one argument group per method, with units and defaults.
    `online`: True for `run` (online methods), None for `extract` (all; lookahead and gap
    bridging with --online), False for `sheet` / `plot` (offline only)."""
    from .methods.curvefit import DEFAULT_KEY_COST, DEFAULT_SMOOTH, DEFAULT_TOL
    from .methods.isodata import CLUSTER_SECONDS, OUTLIER_FENCE
    from .methods.optimal import DEFAULT_MAX_SEGMENT, DEFAULT_RATE
    from .methods.saliency import AUTO_SECONDS, AUTO_SPEED_THRESHOLD, PRESETS
    from .methods.simplify import DEFAULT_TOLERANCE
    from .online import DEFAULT_MAX_BRIDGE_FRAMES

    low, high = PRESETS["low"], PRESETS["high"]
    g = p.add_argument_group("saliency (multiscale motion saliency, Halit & Capin)")
    g.add_argument("--preset", choices=("auto", *PRESETS),
                   help=f"default auto: high (sigma {high[0]:g}, k {high[1]}) if the body moves "
                        f">= {AUTO_SPEED_THRESHOLD} body heights/s over the first "
                        f"{AUTO_SECONDS:g} s, else low (sigma {low[0]:g}, k {low[1]}); online "
                        f"decides after those {AUTO_SECONDS:g} s too")
    g.add_argument("--sigma", type=float, metavar="FRAMES",
                   help="base scale in frames (default: the preset's)")
    g.add_argument("--k", type=int, metavar="N", help="PCA curves (default: the preset's)")
    g.add_argument("--no-contact", action="store_true",
                   help="no foot-contact curves (default: the ankle heights replace the "
                        "last two curves)")
    g.add_argument("--variance-rule", action="store_true",
                   help="k = at least the curves reaching 90 %% of the variance")
    if online is not False:
        g.add_argument("--update-every", type=int, metavar="FRAMES",
                       help="online: recompute the PCA basis at least this often (default 1200)")
    g = p.add_argument_group("speed (speed minima, Miura)")
    g.add_argument("--f-c", type=float, metavar="HZ",
                   help="low-pass cut-off of the joint speeds (default 10 Hz)")
    g.add_argument("--f-max", type=float, metavar="HZ", help="finest scale (default 8 Hz)")
    g.add_argument("--f-min", type=float, metavar="HZ", help="coarsest scale (default 0.2 Hz)")
    g.add_argument("--scale-ratio", type=float, metavar="R",
                   help="ratio of successive scales (default 0.95)")
    g.add_argument("--mojena-k", type=float, metavar="K",
                   help="Mojena constant of the Ward cut-off, larger: fewer keys (default 2.75)")
    if online is not False:
        g.add_argument("--cutoff-history", type=int, metavar="FRAMES",
                       help="online: frames of candidates feeding the cut-off (default 7200)")
        g.add_argument("--warmup-candidates", type=int, metavar="N",
                       help="online: candidates before the cut-off is trusted (default 20)")
    g = p.add_argument_group("simplify (curve simplification)")
    g.add_argument("--simplify-tolerance", type=float, metavar="ERR",
                   help="largest RMS joint error of the straight line between keys: body "
                        "heights with --space positions (default "
                        f"{DEFAULT_TOLERANCE['positions']:g}), degrees with channels (default "
                        f"{DEFAULT_TOLERANCE['channels']:g})")
    g.add_argument("--ratio", type=float,
                   help="instead: largest error / chord length (Önder)")
    g.add_argument("--space", choices=("positions", "channels"), default="positions",
                   help="simplify and decimate: body-frame joint positions in body heights "
                        "(default) or channel values (rotations unwrapped)")
    if online is not False:
        g.add_argument("--merge", type=int, metavar="FRAMES",
                       help="online: a key this close after the last committed one is taken "
                            "to be it (no near-duplicates; default 8)")
        g.add_argument("--max-span", type=int, metavar="FRAMES",
                       help="online: longest open segment (default 8 x lookahead)")
    g = p.add_argument_group("optimal (penalised dynamic programming)")
    g.add_argument("--rate", type=float, metavar="KEYS_PER_S",
                   help=f"keys per second (default {DEFAULT_RATE:g})")
    g.add_argument("--optimal-tolerance", type=float, metavar="ERR",
                   help="instead: largest mean per-frame error between keys (body heights^2)")
    g.add_argument("--lam", type=float, metavar="PENALTY",
                   help="instead: fixed cost per key (frames x body heights^2)")
    g.add_argument("--max-segment", type=float, metavar="SECONDS",
                   help=f"longest stretch between keys (default {DEFAULT_MAX_SEGMENT:g} s)")
    g.add_argument("--root-translation", action="store_true",
                   help="include the root's path in the error (default: body frame only)")
    if online is not True:
        g = p.add_argument_group("isodata (clustering, Zhang et al.)")
        g.add_argument("--cluster-seconds", type=float, metavar="SECONDS",
                       help="expected cluster duration, smaller: more keys (default "
                            f"{CLUSTER_SECONDS:.3g} s)")
        g.add_argument("--max-merges", type=int, metavar="N",
                       help="most class merges per iteration (default: unlimited)")
        g.add_argument("--outlier-fence", type=float, metavar="IQR",
                       help="distances beyond Q3 + IQR x this (pose glitches) stay out of the "
                            f"two-class cut (default {OUTLIER_FENCE:g})")
        g = p.add_argument_group("curvefit (per-channel Hermite keys, Önder)")
        g.add_argument("--smooth", type=float, metavar="S",
                       help=f"smoothing weight, smaller: more keys (default {DEFAULT_SMOOTH:g})")
        g.add_argument("--key-cost", type=float, metavar="C",
                       help=f"cost per key, smaller: more keys (default {DEFAULT_KEY_COST:g})")
        g.add_argument("--curvefit-tol", type=float, metavar="TOL",
                       help="a channel stops when a pass lowers its cost by less than this "
                            f"fraction (default {DEFAULT_TOL:g})")
        g.add_argument("--max-passes", type=int, metavar="N",
                       help="most refinement passes (default 100)")
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
    g.add_argument("--lookahead", metavar="[METHOD=]FRAMES",
                   help=f"{where}frames a decision may wait (default: the method's, "
                        "saliency 121 (37 with --preset high), speed 120, simplify 60, "
                        "optimal 120)")
    g.add_argument("--max-gap", type=float, metavar="SECONDS",
                   help="insert a key (best frame by the optimal segment cost) in every "
                        "stretch longer than SECONDS without one")
    g.add_argument("--history", metavar="[METHOD=]FRAMES",
                   help=f"{where}past frames kept: saliency (default 10 s), speed (2400), "
                        "simplify (2 x lookahead)")
    g.add_argument("--hop", metavar="[METHOD=]FRAMES",
                   help=f"{where}frames between re-analyses: speed (default lookahead / 5, at "
                        "most 24), simplify (8)")
    g.add_argument("--max-bridge", metavar="FRAMES|SECONDSs",
                   help=f"{where}interpolate over at most this many missing frames (or "
                        f"seconds: 0.1s); a longer gap restarts the windows (default "
                        f"{DEFAULT_MAX_BRIDGE_FRAMES} frames)")

def _add_roles_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--roles", metavar="FILE",
                   help="JSON {role: joint name} for skeletons the built-in tables (CMU, "
                        "Mixamo, Axis, Rokoko, Xsens, Unity/VMC) do not name")


def _add_dashboard_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--dashboard", type=int, nargs="?", const=8765, metavar="PORT",
                   help="serve the live page on http://127.0.0.1:PORT/ (default port 8765; "
                        "0 picks a free one)")
    p.add_argument("--log", metavar="PATH",
                   help="dashboard: JSON Lines session log for events and annotations "
                        "(default: the jsonl: sink, else session-<UTC time>.jsonl)")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every subcommand."""
    parser = argparse.ArgumentParser(prog="streamkey", description=__doc__)
    parser.add_argument("--version", action="version", version=f"streamkey {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("extract", help="keyframes of BVH/AMC files or folders (JSON or CSV)")
    p.add_argument("paths", nargs="+", metavar="FILE_OR_DIR")
    p.add_argument("--method", default="saliency",
                   help="saliency, speed, simplify, uniform, decimate, isodata, curvefit, "
                        "optimal, a comma list, or all")
    p.add_argument("-v", "--verbose", action="store_true",
                   help="print derived thresholds (isodata) to stderr")
    p.add_argument("--format", choices=("json", "csv"), default="json")
    p.add_argument("-o", "--output", default="-", help="output file (default: stdout)")
    p.add_argument("--online", action="store_true",
                   help="run the online keyframers over each file as if streamed")
    add_playable_options(p, live=False)
    p.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    p.add_argument("--export-bvh", metavar="OUT",
                   help="write the keyposes-only BVH (+ OUT.keys.json with their original "
                        "frames); several files/methods: a pattern with {stem} and {method}")
    p.add_argument("--export-reconstructed", metavar="OUT",
                   help="write the motion interpolated from the keyframes only (BVH); "
                        "pattern as for --export-bvh")
    _add_roles_option(p)
    _add_method_options(p, online=None)
    p.add_argument("--engine", choices=("local", "ray", "dask"), default="local",
                   help="run the files on a Ray or Dask cluster (default: this process); "
                        "needs streamkey[cluster]")
    p.add_argument("--address", help="ray/dask: an existing cluster (default: a new local one)")
    p.add_argument("--workers", type=int, help="ray/dask local cluster: worker processes "
                   "(default: one per core)")
    p.set_defaults(func=cmd_extract)

    p = sub.add_parser("replay", help="send a BVH/AMC file as a paced frame stream")
    p.add_argument("file")
    p.add_argument("--to", action="append", required=True, metavar="ADDR",
                   help="osc://HOST:PORT, zmq+tcp://HOST:PORT (binds a publisher) or -")
    p.add_argument("--rate", type=float, help="frames per second (default: the file's)")
    p.add_argument("--speed", type=float, default=1.0, help="playback speed factor")
    p.add_argument("--loop", action="store_true", help="start over at the end, seq continuing")
    p.add_argument("--start", type=int, help="first frame (file numbering)")
    p.add_argument("--end", type=int, help="frame to stop before (file numbering)")
    p.add_argument("--frames", type=int, help="stop after sending this many frames")
    p.add_argument("--listen", help="bind publishers to this host instead of 127.0.0.1")
    p.add_argument("--wait", type=float, default=2.0,
                   help="ZeroMQ: seconds to wait for a subscriber before sending")
    p.add_argument("--stream", metavar="NAME",
                   help="stream id on the wire (OSC /streamkey/NAME/frame, ZeroMQ topic "
                        "NAME/frame, JSON Lines \"stream\"); default: the unnamed stream")
    p.set_defaults(func=cmd_replay)

    p = sub.add_parser("run", help="live keyframes: a source -> keyframers -> sinks")
    p.add_argument("--from", dest="source", required=True, metavar="ADDR",
                   help="osc://HOST:PORT, zmq+tcp://HOST:PORT[?pattern=pull], a file, - "
                        "(JSON Lines on stdin), axis+tcp://HOST:7001 (Axis Neuron), "
                        "vmc://127.0.0.1:39539 (VMC)")
    p.add_argument("--skeleton", help="BVH/AMC file with the stream's skeleton (else it comes "
                   "from a /streamkey/skeleton message, the stdin skeleton line, or the "
                   "built-in Axis / humanoid table)")
    p.add_argument("--method", default="all",
                   help="saliency, speed, simplify, optimal, a list, or all")
    p.add_argument("--to", action="append", metavar="ADDR",
                   help="osc://, zmq+tcp://, ws://, jsonl:PATH or - (default: -)")
    p.add_argument("--listen", help="let listeners bind to this host instead of 127.0.0.1")
    p.add_argument("--stream", default="default",
                   help="name of the unnamed stream (frames without a stream id)")
    p.add_argument("--max-streams", type=int, default=64, metavar="N",
                   help="serve at most N streams at once; frames of more are refused and "
                        "counted (default 64)")
    p.add_argument("--stream-idle", type=float, metavar="SECONDS",
                   help="retire a stream (flush its keyframers) after SECONDS without a "
                        "frame; it starts afresh if it comes back (default: never)")
    p.add_argument("--osc-layout", choices=("numeric", "compact"),
                   help="osc:// sinks: numeric (default: /streamkey/STREAM/METHOD/keyframe "
                        "i f f i, one bundle per frame) or compact (/streamkey/keyframe "
                        "s s i f f i); same as osc://HOST:PORT?layout=...")
    p.add_argument("--summary", help="also write the run summary as JSON to this file")
    p.add_argument("--reset-on-gap", action="store_true",
                   help="a gap too long to bridge (or a source restart) forgets the methods' "
                        "running statistics too (default: only the windows restart)")
    p.add_argument("--fast", action="store_true", help="file source: as fast as possible")
    p.add_argument("--idle-exit", type=float, metavar="SECONDS",
                   help="stop once frames have flowed and then none came for SECONDS "
                        "(default: run until Ctrl-C / SIGTERM)")
    p.add_argument("--realtime", action="store_true",
                   help="run ahead of ordinary processes (SCHED_RR 10 where allowed, else "
                        "nice -10), so frames do not wait for a busy machine's other work")
    add_playable_options(p)
    _add_dashboard_options(p)
    _add_roles_option(p)
    _add_method_options(p, online=True)
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("eval", help="evaluation tables (thesis Table 4.1/4.2) for a folder")
    p.add_argument("folder")
    p.add_argument("-o", "--output", default="results/eval", help="output folder")
    p.add_argument("-q", "--quiet", action="store_true")
    p.set_defaults(func=cmd_eval)

    p = sub.add_parser("demo", help="run the keyframers live on the embedded demo motion")
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--offline", action="store_true", help="offline methods instead of online")
    p.add_argument("--fast", action="store_true", help="as fast as possible, not at 120 Hz")
    _add_dashboard_options(p)
    p.add_argument("--listen", help="dashboard: bind to this host instead of 127.0.0.1 (the "
                   "page then needs the token printed in its URL)")
    p.set_defaults(func=cmd_demo, lookahead=None, sigma=None, k=None, no_contact=False,
                   tolerance=None, ratio=None, count=None, space="positions", rate=None,
                   max_segment=None, max_gap=None)

    p = sub.add_parser("sheet", help="contact sheet: a clip's keyposes as stick figures (PNG)")
    p.add_argument("file")
    p.add_argument("--method", default="saliency", help="one method (default: saliency)")
    p.add_argument("-o", "--output", default="sheet.png", help="PNG file (default: sheet.png)")
    p.add_argument("--columns", type=int, default=10, help="figures per row (default: 10)")
    p.add_argument("--per-page", type=int, default=60, metavar="N",
                   help="keyposes per page; more go to OUT-p1.png, OUT-p2.png, ... (default: "
                        "60; 0: one page)")
    p.add_argument("--view", choices=("front", "three-quarter", "side"),
                   default="three-quarter", help="camera, body-aligned (default: three-quarter)")
    _add_method_options(p, online=False)
    _add_roles_option(p)
    p.set_defaults(func=cmd_sheet)

    p = sub.add_parser("plot", help="a clip's driving signals with keyframes marked (PNG)")
    p.add_argument("file")
    p.add_argument("--method", default="saliency,speed",
                   help="methods to mark, a comma list or all (default: saliency,speed)")
    p.add_argument("-o", "--output", default="plot.png", help="PNG file (default: plot.png)")
    _add_method_options(p, online=False)
    _add_roles_option(p)
    p.set_defaults(func=cmd_plot)

    from .cluster.command import add_cluster_parser  # cluster run (issue 14 §5)

    p = add_cluster_parser(sub)
    _add_roles_option(p)
    p.set_defaults(func=cmd_cluster, sigma=None, k=None, no_contact=False, tolerance=None,
                   ratio=None, count=None, space="positions", rate=None, max_segment=None,
                   max_gap=None)

    p = sub.add_parser("bench", help="benchmark speed and memory; results written to files")
    p.add_argument("--offline", action="store_true")
    p.add_argument("--online", action="store_true")
    p.add_argument("--agreement", action="store_true",
                   help="online vs offline F1 against lookahead on every shared clip (slow)")
    p.add_argument("--memory", action="store_true",
                   help="live: RSS over an accelerated 1-hour stream with every sink")
    p.add_argument("--latency", action="store_true", help="live: replay and run as processes, "
                   "an external receiver, OSC and ZeroMQ at 120 Hz, all methods")
    p.add_argument("--ws-clients", dest="ws_clients", action="store_true",
                   help="live: event latency with 0, 100 and 300 WebSocket clients")
    p.add_argument("--streams", action="store_true", help="live: due-event latency for 1-16 "
                   "streams in one process, due-first scheduling on and off")
    p.add_argument("--quick", action="store_true",
                   help="shorter runs: 20,000-frame motion and stream (default benches under "
                        "2 minutes), shorter live benches")
    p.add_argument("--engines", action="store_true", help="extract DIR on local, Ray and "
                   "Dask: wall and CPU (needs streamkey[cluster])")
    p.add_argument("--playable", action="store_true", help="provisional lead, cancel share "
                   "and pose-to-event delay per online method over every clip of --data")
    p.add_argument("--perf", action="store_true",
                   help="per-frame CPU time on a long stream and offline growth exponents")
    from .bench_robustness import add_arguments as robustness_arguments

    robustness_arguments(p)  # --robustness, --clips, --variants
    p.add_argument("--frames", type=int, default=100_000, help="offline motion length")
    p.add_argument("--data", help="folder of CMU clips (default: ../shared/data/cmu if present)")
    p.add_argument("-o", "--output", default="results", help="output folder")
    p.set_defaults(func=cmd_bench)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit code (2 for input and usage errors)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except StreamkeyError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return 0
    except OSError as exc:  # the environment, not the data: an output path, a port, a disk
        from .inputs import os_reason

        where = exc.filename if exc.filename is not None else args.command
        print(f"error: {where}: {os_reason(exc)}", file=sys.stderr)
        return 2
