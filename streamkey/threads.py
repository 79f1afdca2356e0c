"""BLAS/OpenMP thread defaults: one thread per process unless the user says otherwise.

streamkey's numerical work is many small matrix operations; a multi-threaded BLAS only adds
spinning threads that compete with the next file or stream for the same cores (measured on
2 cores: the CLI burnt 2.3x the CPU for a slower batch). The variables must be set before
numpy loads its BLAS, so `streamkey/__init__.py` calls `single_thread_defaults()` first and
worker processes (Ray, Dask) get the same values in their environment at start-up.
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping

__all__ = ["THREAD_VARIABLES", "single_thread_defaults"]

THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                    "BLIS_NUM_THREADS", "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")


def single_thread_defaults(environ: MutableMapping[str, str] | None = None) -> dict[str, str]:
    """Set every unset thread variable to 1 (a value the user set is kept); returns them all,
    ready to hand to worker processes."""
    env = os.environ if environ is None else environ
    for name in THREAD_VARIABLES:
        env.setdefault(name, "1")
    return {name: env[name] for name in THREAD_VARIABLES}
