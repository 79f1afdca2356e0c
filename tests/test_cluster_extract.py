"""`extract --engine ray|dask` (issue 14 §6): byte-identical to the local run on the shared
clips, progress from the engine's futures, bad files reported the same way; BLAS/OpenMP
threads default to one per process."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

pytestmark = pytest.mark.cluster


def _extract(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "streamkey", "extract", *args],
                          capture_output=True, timeout=600, env=env)


@pytest.fixture(scope="module")
def corpus(data_dir, tmp_path_factory):
    """The shared clips plus one broken file (its error must come out the same way)."""
    bad = tmp_path_factory.mktemp("bad") / "broken.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n")
    local = _extract(str(data_dir), str(bad), "--method", "saliency,uniform")
    assert local.returncode == 2 and b"broken.bvh" in local.stderr
    return data_dir, bad, local


@pytest.mark.parametrize("engine", ["ray", "dask"])
def test_engine_output_is_byte_identical_to_the_local_run(corpus, engine):
    data_dir, bad, local = corpus
    run = _extract(str(data_dir), str(bad), "--method", "saliency,uniform", "--engine", engine,
                   "--workers", "2")
    assert run.returncode == 2, run.stderr.decode()[-2000:]
    assert run.stdout == local.stdout
    lines = run.stderr.decode().splitlines()
    progress = [line for line in lines if line.startswith("[")]
    n = sum(1 for p in data_dir.iterdir() if p.suffix in (".bvh", ".amc")) + 1
    assert len(progress) == n and progress[-1].startswith(f"[{n}/{n}]")
    assert [line for line in lines if line.startswith("error:")] == [
        line for line in local.stderr.decode().splitlines() if line.startswith("error:")]


def test_cli_and_workers_default_to_one_blas_thread_unless_the_user_says(tmp_path):
    probe = ("import os, streamkey, numpy; "
             "print(os.environ['OPENBLAS_NUM_THREADS'], os.environ['OMP_NUM_THREADS'])")
    env = {k: v for k, v in os.environ.items() if not k.endswith("_THREADS")}
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, env=env,
                         check=True).stdout.split()
    assert out == ["1", "1"]
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         env={**env, "OPENBLAS_NUM_THREADS": "3"}, check=True).stdout.split()
    assert out == ["3", "1"]


def test_engine_options_are_checked(data_dir):
    run = _extract(str(data_dir / "02_01.bvh"), "--address", "127.0.0.1:1")
    assert run.returncode == 2
    assert run.stderr.decode().strip() == "error: --address needs --engine ray or dask"
