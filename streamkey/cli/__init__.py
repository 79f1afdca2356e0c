"""The `streamkey` command line (`streamkey = "streamkey.cli:main"`, `python -m streamkey`).

`main` builds the parser from one module per command (`extract`, `replay`, `run`, `eval`,
`demo`, `figures` for sheet and plot, `cluster`, `bench`); the method options come from the
parameters declared in `streamkey.methods.params` (`options`). Argument parsing lives here
only: the library takes plain values.
"""

from __future__ import annotations

from .main import build_parser, main
from .options import method_params as _method_params  # noqa: F401 - tests build params
from .options import online_params as _online_params  # noqa: F401

__all__ = ["main", "build_parser"]
