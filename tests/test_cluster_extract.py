"""`extract --engine ray|dask`: byte-identical to the local run on the shared
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


@pytest.mark.parametrize("option", [["--update-every", "600"], ["--lookahead", "60"]])
def test_online_engine_takes_the_online_options_and_matches_the_local_run(data_dir, tmp_path,
                                                                          option):
    """`extract DIR --online --engine dask` with an online-only option runs (it used to be
    refused with "online only; add --online") and gives the local run's bytes."""
    folder = tmp_path / "clips"
    folder.mkdir()
    for name in ("09_01.bvh", "02_01.bvh"):
        (folder / name).symlink_to(data_dir / name)
    argv = [str(folder), "--online", "--method", "saliency,speed", "-q", *option]
    local = _extract(*argv)
    assert local.returncode == 0, local.stderr.decode()[-2000:]
    run = _extract(*argv, "--engine", "dask", "--workers", "1")
    assert run.returncode == 0, run.stderr.decode()[-2000:]
    assert run.stdout == local.stdout
    want = 60 if option[0] == "--lookahead" else None
    if want is not None:
        import json

        files = json.loads(run.stdout)["files"]
        assert {m["params"]["lookahead"] for f in files for m in f["methods"].values()} == {want}
