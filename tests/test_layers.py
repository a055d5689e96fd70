"""The package layering, read from the source's import statements (ast): collect and train depend on
crane_io, never the reverse; train depends on the physics, not on the simulator or the bus; the physics
knows neither the bus nor the simulator; crane_io's library modules import no click."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _imports(package: str):
    """(file, imported module) for every import in a package, relative imports resolved."""
    for path in sorted((ROOT / package.replace(".", "/")).rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        pkg = parts if path.name == "__init__.py" else parts[:-1]
        if path.name == "__init__.py":
            pkg = parts[:-1]
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    yield path.relative_to(ROOT).as_posix(), alias.name
            elif isinstance(node, ast.ImportFrom):
                base = pkg[:len(pkg) - node.level + 1] if node.level else []
                mod = ".".join(base + ([node.module] if node.module else []))
                yield path.relative_to(ROOT).as_posix(), mod
                for alias in node.names:  # `from crane_io import sim` names a module too
                    yield path.relative_to(ROOT).as_posix(), f"{mod}.{alias.name}"


def _offending(package, forbidden, allowed=()):
    return sorted({(f, m) for f, m in _imports(package)
                   if any(m == x or m.startswith(x + ".") for x in forbidden) and (f, m) not in allowed})


def test_the_imports_are_resolved():  # the test reads real imports, or the others could not fail
    found = set(_imports("train"))
    assert ("train/api.py", "train.evaluation.compare") in found
    assert any(m.startswith("crane_io.physics") for _, m in found)


def test_crane_io_never_imports_collect_or_train():
    assert _offending("crane_io", ("collect", "train")) == []


def test_the_physics_knows_neither_the_bus_nor_the_simulator():
    assert _offending("crane_io.physics", ("crane_io.sim", "crane_io.dynamixel")) == []


def test_the_bus_layer_knows_no_physics_and_the_simulator_only_for_dxlsim_urls():
    assert _offending("crane_io.dynamixel", ("crane_io.physics",)) == []
    # dxlsim://NAME ports register their pyserial handler on first use; nothing else of the simulator
    assert _offending("crane_io.dynamixel", ("crane_io.sim",)) == [
        ("crane_io/dynamixel/port.py", "crane_io.sim"),
        ("crane_io/dynamixel/port.py", "crane_io.sim.transport")]


def test_train_depends_on_the_physics_not_on_the_simulator_or_the_bus():
    # `crane-train import` converts other tools' raw servo logs, with the bus layer's unit constants
    allowed = {("train/data/importer.py", "crane_io.dynamixel.units")} | {
        ("train/data/importer.py", f"crane_io.dynamixel.units.{n}")
        for n in ("AMPERE_PER_CURRENT_LSB", "POSITION_CENTER", "RAD_PER_PULSE")}
    assert _offending("train", ("crane_io.sim", "crane_io.dynamixel", "collect"), allowed) == []


def test_collect_never_imports_train():
    assert _offending("collect", ("train",)) == []


@pytest.mark.parametrize("package", ["crane_io.dynamixel", "crane_io.physics", "crane_io.sim"])
def test_crane_ios_library_modules_import_no_click(package):
    assert _offending(package, ("click",)) == []
    others = [(f, m) for f, m in _imports("crane_io") if m == "click" and f != "crane_io/cli_support.py"]
    assert others == []


@pytest.mark.parametrize("package", ["train", "collect"])
def test_the_library_never_imports_its_command_line(package):
    inward = [(f, m) for f, m in _offending(package, (f"{package}.cli", "click"))
              if not f.startswith(f"{package}/cli")]
    assert inward == []
