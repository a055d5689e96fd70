"""The modelling loop from Python: load, fit, report, diagnose, add the effect, compare.

    python docs/examples/api_tour.py SESSION.h5 WORKDIR

SESSION.h5 is any crane-session file; without one, a 60 s session is recorded first on the simulated
arms with a Coulomb friction hidden on joint 2 (about 45 s of wall time):

    python docs/examples/api_tour.py --record WORKDIR

The test suite runs `tour` on a short simulated session (tests/test_api.py).
"""

from __future__ import annotations

import sys
from pathlib import Path

import train


def tour(session: str | Path, workdir: str | Path, *, say=print) -> dict:
    """The loop on one session; returns what it found and how far the error fell (per joint)."""
    work = Path(workdir)
    # 1. the follower's data, preprocessed the paper's way (50 Hz, causal filters, dead-zone masks)
    ds = train.load_sessions(session)
    say(f"{len(ds.tau)} samples of {', '.join(ds.joint_names)}")

    # 2. the baseline physics model: the rigid body, fitted on the training pool, scored on the test set
    base = train.fit(ds, "rigid-body", scale_to_data=True)
    base.save(work / "rb")
    mse = base.metrics["test"]["mse"]
    say("baseline test MSE (N m)^2: " + ", ".join(f"{j} {v:.3g}" for j, v in mse.items()))

    # 3. where does it fail? A self-contained page with the error over time and against each signal
    page = train.make_report(work / "rb", session, work / "rb.html")
    say(f"report: {page}")

    # 4. what is missing? The library's effects ranked by the held-out error each removes
    found = train.diagnose_model(work / "rb", session)
    best = {j: found.best(j) for j in found.joints}
    named = {j: c.effect for j, c in best.items() if c is not None and c.significant}
    for sentence in found.summary.values():
        say(sentence)

    # 5. add what was found, and watch the error fall on the same held-out samples
    effects = [f"{effect}:joint={joint}" for joint, effect in named.items()]
    better = train.fit(ds, "rigid-body", effects=effects, scale_to_data=True)
    better.save(work / "rb-found")
    table = train.compare_models([work / "rb", work / "rb-found"])
    before, after = (m.test["mse"] for m in table.models)
    fall = {j: before[j] / after[j] for j in table.joints}
    say("MSE fell by " + ", ".join(f"{j} {f:.1f}x" for j, f in fall.items()))
    return {"named": named, "fall": fall, "before": before, "after": after}


if __name__ == "__main__":
    args = sys.argv[1:]
    if len(args) == 2 and args[0] == "--record":
        from collect.runner import RunOptions, run_session

        Path(args[1]).mkdir(parents=True, exist_ok=True)
        recorded = Path(args[1]) / "session.h5"
        run_session(RunOptions(output=recorded, sim=True, plant="hidden-coulomb", duration=60, seed=1,
                               force=True))
        tour(recorded, args[1])
    elif len(args) == 2:
        Path(args[1]).mkdir(parents=True, exist_ok=True)
        tour(args[0], args[1])
    else:
        sys.exit(__doc__)
