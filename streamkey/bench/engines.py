"""`streamkey bench --engines`: wall and CPU time of `extract DIR` on each engine (local,
Ray, Dask), each as its own process; CPU is summed over the whole process tree (the engine's
workers included) by sampling /proc, and the outputs are checked byte-identical."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from ..threads import THREAD_VARIABLES

__all__ = ["bench_engines"]

_TICK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def _tree_cpu(root: int, seen: dict[int, float]) -> None:
    """Record the CPU seconds (user + system) of `root` and every descendant."""
    children: dict[int, list[int]] = {}
    stats: dict[int, float] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            text = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        fields = text[text.rindex(")") + 2:].split()
        pid, ppid = int(entry), int(fields[1])
        children.setdefault(ppid, []).append(pid)
        stats[pid] = (int(fields[11]) + int(fields[12])) / _TICK
    todo = [root]
    while todo:
        pid = todo.pop()
        if pid in stats:
            seen[pid] = max(seen.get(pid, 0.0), stats[pid])
        todo.extend(children.get(pid, []))


def _measure(argv: list[str], env: dict[str, str]) -> tuple[float, float, int]:
    seen: dict[int, float] = {}
    started = time.monotonic()
    proc = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    while proc.poll() is None:
        _tree_cpu(proc.pid, seen)
        time.sleep(0.05)
    wall = time.monotonic() - started
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)} failed: {proc.stderr.read().decode()[-500:]}"
                           if proc.stderr else "failed")
    if proc.stderr:
        proc.stderr.close()
    return wall, sum(seen.values()), proc.returncode


def bench_engines(data: Path, out_dir: Path, repeats: int = 3) -> list[Path]:
    """Median wall and CPU of `extract DATA` per engine; writes engines.json and .md."""
    out_dir.mkdir(parents=True, exist_ok=True)
    clean = {k: v for k, v in os.environ.items() if k not in THREAD_VARIABLES}
    many = {**clean, **{k: str(os.cpu_count() or 1) for k in THREAD_VARIABLES}}
    cases: list[tuple[str, list[str], dict[str, str]]] = [
        ("local, BLAS threads = cores (before)", [], many),
        ("local (one BLAS thread, the default)", [], clean),
        ("ray (local, one worker per core)", ["--engine", "ray"], clean),
        ("dask (LocalCluster, one worker per core)", ["--engine", "dask"], clean)]
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        reference: bytes | None = None
        for name, extra, env in cases:
            walls, cpus = [], []
            for r in range(repeats):
                target = Path(tmp) / f"{len(rows)}-{r}.json"
                wall, cpu, _ = _measure([sys.executable, "-m", "streamkey", "extract", str(data),
                                         "-q", "-o", str(target), *extra], env)
                walls.append(wall)
                cpus.append(cpu)
                body = target.read_bytes()
                reference = reference or body
                if body != reference:
                    raise RuntimeError(f"{name}: output differs from the local run")
            walls.sort()
            cpus.sort()
            rows.append({"engine": name, "wall_s": round(walls[len(walls) // 2], 2),
                         "cpu_s": round(cpus[len(cpus) // 2], 2), "repeats": repeats,
                         "identical_output": True})
    files = len([p for p in data.iterdir() if p.suffix.lower() in (".bvh", ".amc")])
    result = {"data": str(data), "files": files, "cores": os.cpu_count(), "rows": rows}
    json_path = out_dir / "engines.json"
    json_path.write_text(json.dumps(result, indent=1) + "\n")
    md = ["| engine | wall (s) | CPU (s) |", "|---|---:|---:|"]
    md += [f"| {r['engine']} | {r['wall_s']} | {r['cpu_s']} |" for r in rows]
    md_path = out_dir / "engines.md"
    md_path.write_text(f"`extract` over {files} files, {os.cpu_count()} cores, median of "
                       f"{repeats} (CPU summed over every process of the run)\n\n"
                       + "\n".join(md) + "\n")
    return [json_path, md_path]
