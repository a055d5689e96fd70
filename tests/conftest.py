"""Suite-wide isolation: the user's own calibrations and announced simulator links never reach a test,
and an effect a test registers (a user effect file) leaves the effects library when the test ends.

Every test gets its own (empty) configuration directory (crane_io.dynamixel.calibration) and runtime directory
(crane_io.dynamixel.link_registry); subprocesses a test starts inherit them through the environment."""

import pytest

from crane_io.dynamixel.calibration import CONFIG_ENV
from crane_io.dynamixel.link_registry import RUNTIME_ENV
from crane_io.physics import effects


@pytest.fixture(autouse=True)
def _own_user_dirs(tmp_path_factory, monkeypatch):
    base = tmp_path_factory.mktemp("user")
    monkeypatch.setenv(CONFIG_ENV, str(base / "config"))
    monkeypatch.setenv(RUNTIME_ENV, str(base / "runtime"))


@pytest.fixture(autouse=True, scope="module")
def _module_effects_library():
    """The effects library as it was before the module: what a module-scoped fixture registers (a fit with
    an effect file) leaves with the module instead of staying for every later module."""
    saved = dict(effects._REGISTRY)
    yield
    effects._REGISTRY.clear()
    effects._REGISTRY.update(saved)


@pytest.fixture(autouse=True)
def _own_effects_library():
    """The effects library as it was before the test (after its module's fixtures): a user effect one test
    registers would otherwise be a diagnosis candidate in every later test (a cubic drag left by
    test_loop_model changed what test_discovery discovers when it ran after it)."""
    saved = dict(effects._REGISTRY)
    yield
    effects._REGISTRY.clear()
    effects._REGISTRY.update(saved)
