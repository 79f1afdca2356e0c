"""`streamkey extract`: keyframes of BVH/AMC files and folders, as JSON or CSV."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from .common import Heartbeat, progress, write
from .options import (
    add_method_options,
    add_playable_options,
    add_roles_option,
    method_params,
    roles_of,
)

__all__ = ["add_parser", "run"]


def add_parser(sub: Any) -> None:
    """The `extract` subcommand."""
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
    add_roles_option(p)
    add_method_options(p, online=None)
    p.add_argument("--engine", choices=("local", "ray", "dask"), default="local",
                   help="run the files on a Ray or Dask cluster (default: this process); "
                        "needs streamkey[cluster]")
    p.add_argument("--address", help="ray/dask: an existing cluster (default: a new local one)")
    p.add_argument("--workers", type=int, help="ray/dask local cluster: worker processes "
                   "(default: one per core)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Keyframes of every file (offline, or the online keyframers as if streamed); a bad
    file is its own `error:` line and exit code 2, the others still run."""
    from ..batch import (
        extract_files,
        extract_files_online,
        find_motion_files,
        results_csv,
        results_json,
    )
    from ..methods import parse_methods
    from ..streaming import check_online_params

    paths = find_motion_files(args.paths)
    methods = parse_methods(args.method, online=args.online)
    # --max-gap, --min-interval and the lookahead ride in params, applied by the library
    params = method_params(args, online=args.online)
    if args.online:
        check_online_params(methods, params)
    results: list[Any]
    beat = Heartbeat(args.quiet)
    if args.engine != "local" or args.address:  # a cluster engine: same files, same JSON
        from ..cluster.engines import extract_with_engine

        results = extract_with_engine(paths, methods, params, args.engine, args.address,
                                      args.workers, progress(args.quiet), roles_of(args),
                                      args.online)
    else:
        extract = extract_files_online if args.online else extract_files
        try:
            results = list(extract(paths, methods, params, progress=progress(args.quiet, beat),
                                   roles=roles_of(args)))
        finally:
            beat.stop()
    write(results_json(results) if args.format == "json" else results_csv(results), args.output)
    _export(results, args)
    failed = [r for r in results if r.error]
    for r in failed:
        print(f"error: {r.error}", file=sys.stderr)
    return 2 if failed else 0


def _export(results: list[Any], args: argparse.Namespace) -> None:
    """`--export-bvh / --export-reconstructed`: keyframes back out as BVH."""
    from ..export import export_results

    for pattern, rebuilt in ((args.export_bvh, False), (args.export_reconstructed, True)):
        if pattern:
            for path in export_results(results, pattern, reconstructed=rebuilt):
                print(f"wrote {path}", file=sys.stderr)
