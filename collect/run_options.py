"""What one collection run is asked to do (`RunOptions`) and what it did (`RunResult`).

    result = run_session(RunOptions(output="session.h5", sim=True, duration=60))

The options are plain values, checked before anything starts (collect/startup.py `check_options`,
`check_ports`, `check_output`; `check_run_outputs` here: no output is an input or another output); the
run (collect/runner.py `BilateralRun`) hands each part of the collector only the values it needs. A
sentence about an option names it by its field name in backquotes (`duration`); crane-collect shows its
flag instead (crane_io.cli_support.cli_errors).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .bilateral_loop import RunContext
    from .safety import Breach


@dataclass
class RunOptions:
    output: str | Path
    sim: bool = False
    plant: str | None = None  # preset name or TOML path for the simulated arms ("simple": SimplePlant)
    seed: int = 0
    duration: float | None = None  # s of bilateral control; None: until Ctrl+C / SIGTERM
    rate: float | None = None  # Hz, overrides the configuration
    config: str | Path | None = None
    realtime: bool = False  # sim only: the loop paced by the wall clock (the simulated arms stay lockstep)
    leader_port: str | None = None
    follower_port: str | None = None
    force: bool = False
    status: bool = True  # live status line on stderr
    stream: object = None  # where status and summary go (default sys.stderr)
    truth: str | Path | None = None  # sim only: write the follower plant's truth (JSON) here
    truth_trace: str | Path | None = None  # sim only: the plants' true external torques per row (HDF5)
    model: str | Path | None = None  # learned model directory for the follower's reaction-force observer
    leader_model: str | Path | None = None  # ... for the leader's
    arm_model: str | Path | None = None  # an identified arm model (TOML): both arms' nominal observer model
    hand_on: str = "leader"  # the arm the operator's hand moves ("follower": leader data free of a hand)
    task: str | None = None  # sim only: the simulated operator's task ("free", "contact"); None: config's
    joints: str | list | tuple | None = None  # bilateral joints ("joint1,joint2" or names); None: config's
    view: bool = False  # live view in a spawned rerun viewer (collect/live_view.py)
    view_save: str | Path | None = None  # live view written to this .rrd file instead of a viewer
    view_every: int = 10  # the view samples every N-th cycle
    leader_calibration: str | Path | None = None  # the leader's calibration file (crane_io.dynamixel)
    follower_calibration: str | Path | None = None  # ... for the follower
    calibrate: bool = True  # hardware: use each adapter's stored calibration (False: none)
    skip_selftest: bool = False  # hardware: run without a passing self-test on record (selftest_record)
    # test hook: called every bilateral cycle with (cycle index, RunContext) before the bus reads
    on_cycle: Callable[[int, RunContext], None] | None = None


def run_inputs(opts: RunOptions) -> list:
    """Every file or folder a run reads: the configuration, a plant TOML, the models, the calibration
    files (given, or the stored ones' folder on hardware) and, on hardware, the two ports."""
    from crane_io.dynamixel.calibration import config_dir

    inputs = [opts.config, opts.model, opts.leader_model, opts.arm_model, opts.leader_calibration,
              opts.follower_calibration]
    if opts.plant is not None and Path(opts.plant).exists():  # a TOML path, not a preset's name
        inputs.append(opts.plant)
    if not opts.sim:  # a port is a device file (a folder given as one is refused when it is opened)
        inputs += [p for p in (opts.leader_port, opts.follower_port) if p and not Path(p).is_dir()]
        if opts.calibrate:
            inputs.append(config_dir())
    return [p for p in inputs if p is not None and str(p) != ""]


def check_run_outputs(opts: RunOptions) -> None:
    """Before any hardware is touched: the session file, the truth file, the truth trace and the live
    view's file are each checked against every input of the run and against each other, links
    resolved (crane_io.output_files); an existing truth, trace or view file is replaced only with
    `force`. The session file's existence and folder are collect/startup.py `check_output`'s."""
    from crane_io.output_files import check_distinct, check_output

    outputs = [(opts.output, "session file"), (opts.truth, "truth file"), (opts.truth_trace, "truth trace"),
               (opts.view_save, "rerun file")]
    given = [(k, path, what) for k, (path, what) in enumerate(outputs) if path is not None and str(path)]
    inputs = run_inputs(opts)
    for k, path, what in given:
        others = [p for i, p, _ in given if i != k]
        if k == 0:
            check_distinct(path, inputs=inputs, others=others, what=what)
        else:
            check_output(path, inputs=inputs, force=opts.force, what=what, others=others)


@dataclass
class RunResult:
    path: Path
    cycles: int
    duration_s: float  # session time covered
    wall_s: float
    end_reason: str  # "duration", "interrupted", "terminated", "safety_stop", "error"
    breach: Breach | None
    summary: dict
    tracking_rms: dict[str, float] = field(default_factory=dict)
