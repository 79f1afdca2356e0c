"""Many machines: corpus batches on Ray or Dask (`extract --engine`) and the live cluster
mode on Ray (`streamkey cluster run`). Needs the `cluster` extra (`pip install
"streamkey[cluster]"`: ray, redis, dask[distributed]); nothing here is imported by the
rest of streamkey unless one of those commands runs.
"""

from __future__ import annotations

from ..errors import UsageError

__all__ = ["require"]


def require(module: str, what: str) -> None:
    """Refuse clearly when an optional cluster dependency is missing."""
    import importlib.util

    if importlib.util.find_spec(module) is None:
        raise UsageError(f"{what} needs the {module!r} package: pip install "
                         f"\"streamkey[cluster]\"")
