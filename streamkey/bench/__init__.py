"""The benchmark harness behind `streamkey bench`: measurements of the library, kept out of
it (nothing in streamkey's core imports this package).

- `core`: offline and online speed and memory, the online/offline agreement, per-frame CPU
  (`run_bench` dispatches every kind, the live ones included).
- `live`: memory, latency and WebSocket-client benches of `run` as real processes.
- `streams`: due-event latency for many streams in one process.
- `playable`: provisional lead, cancel share and pose-to-event delay per online method.
- `engines`: `extract DIR` on the local, Ray and Dask engines.

A new bench is one more module here and one more flag in `streamkey.cli.bench`.
"""

from __future__ import annotations

from .core import (
    PERF_ONLINE_GOALS,
    QUICK,
    BenchInterrupted,
    bench_perf_offline,
    bench_perf_online,
    default_data_dir,
    long_motion,
    run_bench,
)

__all__ = ["run_bench", "long_motion", "default_data_dir", "BenchInterrupted", "QUICK",
           "PERF_ONLINE_GOALS", "bench_perf_offline", "bench_perf_online"]
