"""`streamkey sheet` and `streamkey plot`: a clip's keyposes and signals as pictures."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from ..keyframes import Keyframes
from ..motion import Motion
from .common import read
from .options import add_method_options, add_roles_option, method_params

__all__ = ["add_parsers", "run_sheet", "run_plot"]


def add_parsers(sub: Any) -> None:
    """The `sheet` and `plot` subcommands."""
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
    add_method_options(p, online=False)
    add_roles_option(p)
    p.set_defaults(func=run_sheet)

    p = sub.add_parser("plot", help="a clip's driving signals with keyframes marked (PNG)")
    p.add_argument("file")
    p.add_argument("--method", default="saliency,speed",
                   help="methods to mark, a comma list or all (default: saliency,speed)")
    p.add_argument("-o", "--output", default="plot.png", help="PNG file (default: plot.png)")
    add_method_options(p, online=False)
    add_roles_option(p)
    p.set_defaults(func=run_plot)


def _keyframes_of(path: str, method: str,
                  args: argparse.Namespace) -> tuple[Motion, dict[str, Keyframes]]:
    from ..batch import extract_motion, naming
    from ..methods import parse_methods

    names = parse_methods(method)
    motion = read(path, args)
    with naming(path):
        return motion, extract_motion(motion, names, method_params(args))


def run_sheet(args: argparse.Namespace) -> int:
    """The keyposes of one clip as a contact sheet of stick figures."""
    from ..errors import InputError, UsageError
    from ..inputs import display_name
    from ..methods import parse_methods
    from ..sheet import SheetResult, contact_sheet

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
    assert isinstance(sheet, SheetResult)  # with an output path, never a bare Figure
    for page in sheet.pages:
        print(f"wrote {page}", file=sys.stderr)
    print(f"{sheet.figures} keyposes on {len(sheet.pages)} page(s): {sheet.frames}",
          file=sys.stderr)
    return 0


def run_plot(args: argparse.Namespace) -> int:
    """A clip's driving signals with the keyframes of each method marked."""
    from ..sheet import plot_signals

    motion, results = _keyframes_of(args.file, args.method, args)
    print(f"wrote {plot_signals(motion, results, args.output)}", file=sys.stderr)
    return 0
