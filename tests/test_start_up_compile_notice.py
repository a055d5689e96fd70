"""`crane-collect run` says that it compiles the kernels when it does (after an install without
scripts/setup.sh), once, before the alignment; never with `status` off. The compilation is stood in for by
a slow call that misses numba's cache and runs crane_io.jit's notice watch as compile_functions does."""

import collections
import functools
import io
import threading
import types

import pytest

from collect import runner
from collect.kernels import compile_sentence
from collect.runner import RunOptions, run_session
from crane_io import jit


def _slow_compile():
    for _ in range(2):  # two slow modules: said once
        misses = collections.Counter()
        dispatcher = types.SimpleNamespace(stats=types.SimpleNamespace(cache_misses=misses))
        done = jit._notice_watch([dispatcher])
        misses["sig"] += 1  # numba compiles: the signature was not in its cache
        threading.Event().wait(0.3)
        if done is not None:
            done.set()


@pytest.mark.parametrize("status", [True, False])
def test_a_run_that_compiles_says_so_once_before_the_alignment(tmp_path, monkeypatch, status):
    monkeypatch.setattr(runner, "compile_kernels", _slow_compile)
    monkeypatch.setattr(runner, "compile_notice", functools.partial(jit.compile_notice, after_s=0.05))
    out = io.StringIO()
    run_session(RunOptions(output=tmp_path / "s.h5", sim=True, duration=0.02, stream=out, status=status))
    lines = out.getvalue().splitlines()
    if not status:
        assert compile_sentence() not in lines
        return
    assert lines.count(compile_sentence()) == 1
    aligning = [i for i, line in enumerate(lines) if line.startswith("aligning")]
    assert aligning and lines.index(compile_sentence()) < aligning[0]
