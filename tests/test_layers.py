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


# Compiled modules (docs/architecture.md, "Compiled paths") import only numpy, math, numba, crane_io.jit and
# the layout modules listed here for each one (the constants and tables their arrays are laid out by, and
# the compiled modules they call). A new *_kernel.py module must be listed.
COMPILED_ANYWHERE = ("__future__", "numpy", "math", "numba", "crane_io.jit")
COMPILED_LAYOUTS = {
    "collect/controller_kernel.py": ("collect.controller_layout",),
    "collect/operator_kernel.py": ("collect.operator_layout",),
    "crane_io/dynamixel/cycle_kernel.py": ("crane_io.dynamixel.crc_layout",),  # the CRC table and loop
    "crane_io/sim/chain_kernel.py": ("crane_io.dynamixel.crc_layout", "crane_io.dynamixel.units",
                                     "crane_io.dynamixel.control_table"),  # the X series' addresses
    "crane_io/sim/lockstep_kernel.py": (
        "crane_io.dynamixel.control_table",  # the X series' addresses
        "crane_io.dynamixel.units",
        "crane_io.sim.servo",  # the servo memory's size and the servo state's columns
        "crane_io.sim.servo_rules",  # the goal ranges
        "crane_io.sim.chain_kernel", "crane_io.sim.noise_kernel", "crane_io.sim.plant_kernel",  # it calls
    ),
    # ctypes: the numpy generator's state pointer; warnings: a numba whose sampler differs is said once
    "crane_io/sim/noise_kernel.py": ("crane_io.dynamixel.units", "ctypes", "warnings"),
    "crane_io/sim/plant_kernel.py": ("crane_io.sim.plant_layout", "crane_io.sim.plant_rigid",
                                     "crane_io.physics.effect_shapes"),
}
# Modules whose functions a compiled module compiles besides its own (same rule: numpy, math and layouts)
COMPILED_SOURCES = {
    "crane_io/physics/effect_shapes.py": (),  # the built-in effects' shapes, the plant's and the formulas'
    "crane_io/sim/plant_layout.py": ("crane_io.physics.effect_shapes",),
    "crane_io/sim/plant_rigid.py": ("crane_io.sim.plant_layout",),  # the rigid body, both plant steppers'
}


def _modules_imported(path: Path) -> set[str]:
    """The modules a file imports (`from a.b import c` names module a.b.c when that is a module of the tree,
    else a.b; relative imports resolved against the file's package), anywhere in the file."""
    found = set()
    package = path.relative_to(ROOT).parent.parts
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else ()
            module = ".".join([*base, *([node.module] if node.module else [])])
            for alias in node.names:
                sub = f"{module}.{alias.name}"
                is_module = (ROOT / (sub.replace(".", "/") + ".py")).exists()
                found.add(sub if is_module else module)
    return found


def test_every_compiled_module_is_listed():
    kernels = {p.relative_to(ROOT).as_posix() for pkg in ("crane_io", "collect", "train")
               for p in (ROOT / pkg).rglob("*_kernel.py")}
    assert kernels == set(COMPILED_LAYOUTS)


def test_the_imports_of_a_compiled_module_are_resolved():  # or the next test could not fail
    found = _modules_imported(ROOT / "crane_io/sim/lockstep_kernel.py")
    assert {"numpy", "crane_io.sim.chain_kernel", "crane_io.sim.servo", "crane_io.jit"} <= found
    assert "collect.controller_layout" in _modules_imported(ROOT / "collect/controller_kernel.py")  # relative


@pytest.mark.parametrize("module", sorted(COMPILED_LAYOUTS) + sorted(COMPILED_SOURCES))
def test_compiled_modules_import_only_numpy_math_numba_and_their_layout(module):
    allowed = COMPILED_ANYWHERE + {**COMPILED_LAYOUTS, **COMPILED_SOURCES}[module]
    others = sorted(m for m in _modules_imported(ROOT / module)
                    if not any(m == a or m.startswith(a + ".") for a in allowed))
    assert others == [], f"{module} imports {others}: not numpy, math, numba or a layout module of it"
