"""Corpus batches on an engine: `extract DIR --engine local|ray|dask`.

Every engine runs the same `batch.extract_one` per file and `batch.merge_results` puts the
results back in input order, so the JSON is byte-identical to the local run. Progress lines
come as the engine's futures complete. Workers get the BLAS/OpenMP thread variables of this
process (one thread each unless the user set them) before numpy loads: Ray through the job's
`runtime_env`, a local Dask cluster by inheriting this environment (Dask's nanny also sets
them to 1 by default, `distributed.nanny.pre-spawn-environ`). Files are read by the workers:
on several machines the paths must be visible to all of them (a shared file system) and
streamkey installed on every node.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from ..batch import FileResult, extract_one, merge_results
from ..errors import UsageError
from ..threads import single_thread_defaults
from . import require

__all__ = ["ENGINES", "extract_with_engine"]

ENGINES = ("local", "ray", "dask")
Progress = Callable[[int, int, Path], None]


def _one_in(cwd: str, path: Path, *args: Any) -> FileResult:
    """`extract_one` with relative paths resolved against the submitting process' folder
    (engine workers start elsewhere); the result names the path exactly as given."""
    if os.getcwd() != cwd and os.path.isdir(cwd):
        os.chdir(cwd)
    return extract_one(path, *args)


def extract_with_engine(paths: list[Path], methods: list[str],
                        params: dict[str, dict[str, Any]] | None, engine: str = "local",
                        address: str | None = None, workers: int | None = None,
                        progress: Progress | None = None, roles: dict[str, str] | None = None,
                        online: bool = False, lookahead: int | None = None
                        ) -> list[FileResult]:
    """Results of every file in input order, computed by `engine` (a new local instance, or
    the existing cluster at `address`)."""
    if engine not in ENGINES:
        raise UsageError(f"--engine must be one of {', '.join(ENGINES)}, got {engine!r}")
    if engine == "local" and address:
        raise UsageError("--address needs --engine ray or dask")
    args = (methods, params, roles, online, lookahead)
    if engine == "local":
        def local() -> Iterator[tuple[int, FileResult]]:
            for i, path in enumerate(paths):
                result = extract_one(path, *args)
                if progress:
                    progress(i, len(paths), path)
                yield i, result
        return merge_results(paths, local())
    runner = _ray if engine == "ray" else _dask
    return merge_results(paths, _counted(runner(paths, args, address, workers), paths, progress))


def _counted(done: Iterator[tuple[int, FileResult]], paths: list[Path],
             progress: Progress | None) -> Iterator[tuple[int, FileResult]]:
    for n, (i, result) in enumerate(done):
        if progress:
            progress(n, len(paths), paths[i])
        yield i, result


def _ray(paths: list[Path], args: tuple[Any, ...], address: str | None,
         workers: int | None) -> Iterator[tuple[int, FileResult]]:
    require("ray", "--engine ray")
    import ray

    env = single_thread_defaults()
    started = not ray.is_initialized()
    if started:
        # no --address: a new local Ray of our own, even beside a running one (which would
        # otherwise be joined, and refuse num_cpus)
        options: dict[str, Any] = {"address": address} if address else {
            "address": "local", "num_cpus": workers or os.cpu_count() or 1,
            "include_dashboard": False}
        ray.init(**options, runtime_env={"env_vars": env}, logging_level=logging.WARNING,
                 log_to_driver=False, configure_logging=False)
    try:
        task = ray.remote(num_cpus=1, max_retries=1)(_one_in)
        cwd = os.getcwd()
        index = {task.remote(cwd, p, *args): i for i, p in enumerate(paths)}
        pending = list(index)
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for ref in ready:
                yield index[ref], ray.get(ref)
    finally:
        if started:
            ray.shutdown()


def _dask(paths: list[Path], args: tuple[Any, ...], address: str | None,
          workers: int | None) -> Iterator[tuple[int, FileResult]]:
    require("distributed", "--engine dask")
    from distributed import Client, LocalCluster, as_completed

    single_thread_defaults()  # inherited by the local cluster's worker processes
    cluster = None
    if address:
        client = Client(address)
    else:
        # Its logs stay quiet below CRITICAL: a file's error comes back in its result, and
        # on exit a worker's heartbeat can meet the closing scheduler and log a traceback.
        cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                               processes=True, dashboard_address=None,
                               silence_logs=logging.CRITICAL)
        client = Client(cluster)
    try:
        cwd = os.getcwd()
        futures = {client.submit(_one_in, cwd, p, *args, pure=False): i
                   for i, p in enumerate(paths)}
        for future, result in as_completed(futures, with_results=True):
            yield futures[future], result
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
