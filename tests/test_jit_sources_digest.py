"""crane_io.jit names every compiled function's cache entry with a digest of the sources it draws on: the
kernel module and every toolkit module it imports at its top level, transitively, so that an edit of a
layout module (whose constants are compiled into the machine code) never reuses code built from the old
source."""

from __future__ import annotations

import importlib
import sys

import pytest

from crane_io import jit


@pytest.fixture
def package(tmp_path, monkeypatch):
    """A throwaway package `kpkg` (kernel -> layout -> table) that the digest treats as the toolkit's."""
    root = tmp_path / "kpkg"
    root.mkdir()
    (root / "__init__.py").write_text("")
    (root / "table.py").write_text("WIDTH = 4\n")
    (root / "layout.py").write_text("from .table import WIDTH\nROWS = WIDTH * 2\n")
    (root / "kernel.py").write_text("from kpkg.layout import ROWS\n\ndef f(x):\n    return x * ROWS\n")
    (root / "other.py").write_text("VALUE = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(jit, "_PROJECT_PACKAGES", (*jit._PROJECT_PACKAGES, "kpkg"))
    monkeypatch.setattr(jit, "_digests", {})
    yield root
    for name in [m for m in sys.modules if m == "kpkg" or m.startswith("kpkg.")]:
        del sys.modules[name]


def _digest() -> str:
    jit._digests.clear()
    return jit.sources_digest(vars(importlib.import_module("kpkg.kernel")))


def test_the_digest_is_stable_and_follows_imports_transitively(package):
    first = _digest()
    assert _digest() == first
    (package / "other.py").write_text("VALUE = 2\n")  # not imported by the kernel: no change
    assert _digest() == first
    (package / "table.py").write_text("WIDTH = 5\n")  # two imports away
    assert _digest() != first


def test_an_edit_of_the_kernels_own_source_changes_the_digest(package):
    first = _digest()
    (package / "kernel.py").write_text("from kpkg.layout import ROWS\n\ndef f(x):\n    return x + ROWS\n")
    assert _digest() != first


def test_the_toolkits_kernels_digest_the_modules_they_compile_constants_from():
    lockstep = set(jit.module_sources("crane_io.sim.lockstep_kernel"))
    assert {"crane_io.sim.plant_kernel", "crane_io.sim.plant_layout", "crane_io.sim.chain_kernel",
            "crane_io.dynamixel.crc_layout", "crane_io.sim.servo", "crane_io.dynamixel.units"} <= lockstep
    assert "collect.controller_layout" in jit.module_sources("collect.controller_kernel")
