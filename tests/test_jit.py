"""streamkey.jit: kernels compile on first call (numba), call each other, pickle by name,
and warm_up() runs every registered warmer."""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from cmu import DATA

from streamkey import jit


def test_import_streamkey_does_not_import_numba():
    code = "import streamkey, streamkey.cli, streamkey.jit, sys; print('numba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"


def test_kernel_compiles_calls_other_kernels_and_pickles(tmp_path, monkeypatch):
    module = tmp_path / "jit_sample_kernels.py"
    module.write_text(textwrap.dedent('''
        from streamkey.jit import kernel, warmer

        @kernel
        def step(x):
            return 2.0 * x + 1.0

        @kernel
        def total(a):
            s = 0.0
            for v in a:
                s += step(v)
            return s

        WARMED = []

        @warmer
        def warm():
            WARMED.append(total(__import__("numpy").zeros(1)))
    '''))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    import jit_sample_kernels as mod

    a = np.arange(5.0)
    assert mod.total.compiled is None  # nothing compiled before the first call
    assert jit.cache_is_cold([mod.total, mod.step])  # a new module: nothing cached yet
    assert mod.total(a) == float(np.sum(2.0 * a + 1.0))
    assert mod.total.compiled is not None and mod.step.compiled is not None
    assert pickle.loads(pickle.dumps(mod.total)) is mod.total
    assert not jit.cache_is_cold([mod.total, mod.step])  # compiled once: on disk now
    jit.warm_up()
    assert mod.WARMED == [1.0]
    jit._WARMERS.remove(mod.warm)


def test_a_kernel_calls_the_prefetch_hint_by_name_and_keeps_its_result(tmp_path, monkeypatch):
    module = tmp_path / "jit_prefetch_kernels.py"
    module.write_text(textwrap.dedent('''
        from streamkey.jit import kernel, prefetch

        @kernel
        def strided_sum(a, step):
            s = 0.0
            for i in range(0, len(a), step):
                prefetch(a, min(i + 4 * step, len(a) - 1))
                s += a[i]
            return s
    '''))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    import jit_prefetch_kernels as mod

    a = np.arange(1000.0)
    assert mod.strided_sum(a, 8) == float(np.sum(a[::8]))
    assert jit.prefetch not in jit._KERNELS  # nothing of its own in numba's cache
    assert not jit.cache_is_cold([mod.strided_sum])  # the caller is cached as any kernel


_PIPELINE = '''
import sys
from streamkey import jit
from streamkey.io import StreamSpec
from streamkey.online import Pipeline
from streamkey.rigs import humanoid_skeleton
from streamkey.streamtable import keyframers_for
spec = StreamSpec("s", humanoid_skeleton(), 120.0)
Pipeline(keyframers_for(spec, ["saliency", "speed", "simplify", "optimal"]), stream="s")
cold = jit.cache_is_cold()  # before anything runs, as the engine asks it
if sys.argv[1] == "warm":
    jit.warm_up()
print(cold)
'''


@pytest.mark.slow
def test_a_fresh_process_after_warm_up_finds_the_cache_warm(tmp_path):
    """`cache_is_cold()` is what the engine's "compiling the numba kernels" notice rests on:
    True on an empty cache, False in the next process once `warm_up()` ran (every kernel a
    live stream can call is compiled by a warmer, the noise filter's included)."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}

    def cold(step: str) -> str:
        done = subprocess.run([sys.executable, "-P", "-c", _PIPELINE, step], env=env,
                              capture_output=True, text=True, timeout=1800)
        assert done.returncode == 0, done.stderr
        return done.stdout.split()[-1]

    assert cold("warm") == "True"  # an empty cache
    assert cold("check") == "False"  # a fresh process after warm_up: nothing to compile


_STREAM = '''
import sys
from streamkey import jit
from streamkey.amc import read_motion
from streamkey.online import Pipeline
from streamkey.streaming import make_keyframers
motion = read_motion(sys.argv[1])
pipeline = Pipeline(make_keyframers(motion, ["saliency", "speed", "simplify", "optimal"]))
jit.warm_up()
def signatures():
    return {k.__module__ + "." + k.__qualname__: len(k.compiled.signatures)
            for k in jit._KERNELS if k.compiled is not None}
before = signatures()
for frame in motion.frames():
    pipeline.push(frame)
    pipeline.idle()
pipeline.flush()
after = signatures()
print(sorted(name for name in after if after[name] != before.get(name, 0)))
'''


@pytest.mark.slow
def test_no_push_of_a_real_stream_loads_a_kernel_after_warm_up():
    """Loading one kernel signature from numba's cache costs ~7 ms: a live stream must find
    every signature it calls already loaded by `warm_up()` (speed's staged HP trends and its
    minima correspondence were missing: the first analysis' push took 7 ms). Every online
    method on one pipeline over 01_06 (43 s: saliency's spread basis updates, speed's
    analyses, optimal's chunks, the flush), in a fresh process."""
    clip = DATA / "01_06.bvh"
    done = subprocess.run([sys.executable, "-P", "-c", _STREAM, str(clip)], capture_output=True,
                          text=True, timeout=1800)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split("\n")[-2] == "[]"
