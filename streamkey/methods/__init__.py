"""Keyframe extraction methods: one module per method, offline `extract` + online `Online`.

The registry maps the CLI names to the functions; modules are imported on first use.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any, cast

from ..errors import UsageError

__all__ = ["OFFLINE_METHODS", "ONLINE_METHODS", "COUNTED_METHODS", "offline_method",
           "online_class", "parse_methods"]

OFFLINE_METHODS: dict[str, str] = {
    "saliency": "saliency:extract",
    "speed": "speed:extract",
    "simplify": "simplify:extract",
    "uniform": "baselines:uniform",
    "decimate": "baselines:decimate",
    "isodata": "isodata:extract",
    "curvefit": "curvefit:extract",
    "optimal": "optimal:extract",
}
ONLINE_METHODS: dict[str, str] = {
    "saliency": "saliency_auto:AutoOnline",
    "speed": "speed:Online",
    "simplify": "simplify:Online",
    "optimal": "optimal:Online",
}
# Methods that take a target keyframe count (the equal-count comparison of the thesis).
COUNTED_METHODS = ("simplify", "uniform", "decimate", "optimal")


def _load(spec: str) -> object:
    """The object a registry entry ("module:attribute") names, importing its module."""
    module, attr = spec.split(":")
    found: object = getattr(importlib.import_module(f"{__name__}.{module}"), attr)
    return found


def offline_method(name: str) -> Callable[..., Any]:
    """The offline `extract`-style function registered under `name`."""
    if name not in OFFLINE_METHODS:
        raise UsageError(f"unknown method {name!r}; choose from {', '.join(OFFLINE_METHODS)}")
    return cast(Callable[..., Any], _load(OFFLINE_METHODS[name]))


def online_class(name: str) -> type:
    """The online keyframer class registered under `name`."""
    if name not in ONLINE_METHODS:
        raise UsageError(f"no online version of {name!r}; choose from {', '.join(ONLINE_METHODS)}")
    return cast(type, _load(ONLINE_METHODS[name]))


def parse_methods(text: str, online: bool = False) -> list[str]:
    """Comma-separated method names, `all` for every registered one."""
    known = ONLINE_METHODS if online else OFFLINE_METHODS
    names = [n.strip() for n in text.split(",") if n.strip()]
    if names == ["all"]:
        return list(known)
    bad = [n for n in names if n not in known]
    if bad or not names:
        raise UsageError(f"unknown method(s) {', '.join(bad) or text!r}; choose from "
                         f"{', '.join(known)} or all")
    return names
