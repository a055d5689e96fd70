"""Suite-wide isolation: the user's own calibrations and announced simulator links never reach a test.

Every test gets its own (empty) configuration directory (crane_io.dynamixel.calibration) and runtime directory
(crane_io.dynamixel.link_registry); subprocesses a test starts inherit them through the environment."""

import pytest

from crane_io.dynamixel.calibration import CONFIG_ENV
from crane_io.dynamixel.link_registry import RUNTIME_ENV


@pytest.fixture(autouse=True)
def _own_user_dirs(tmp_path_factory, monkeypatch):
    base = tmp_path_factory.mktemp("user")
    monkeypatch.setenv(CONFIG_ENV, str(base / "config"))
    monkeypatch.setenv(RUNTIME_ENV, str(base / "runtime"))
