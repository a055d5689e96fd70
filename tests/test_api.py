"""The Python front door (train/api.py): the modelling loop of docs/examples/api_tour.py runs on a short
simulated session with a hidden Coulomb friction on joint 2, names it and cuts joint 2's error; and the
functions refuse bad input in one sentence, as the commands do."""

import runpy
from pathlib import Path

import numpy as np
import pytest

import train
from crane_io.errors import ConfigError, CraneError
from tests.planted import simulate_session

TOUR = Path(__file__).resolve().parents[1] / "docs" / "examples" / "api_tour.py"


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    path = tmp_path_factory.mktemp("api") / "hidden-coulomb.h5"
    simulate_session(path, "hidden-coulomb", 60.0, seed=0)
    return path


def test_the_api_tour_names_the_hidden_friction_and_the_error_falls(session, tmp_path):
    lines = []
    found = runpy.run_path(str(TOUR))["tour"](session, tmp_path, say=lines.append)
    assert found["named"].get("joint2") in ("coulomb", "stiction", "coulomb-asym"), lines
    assert found["fall"]["joint2"] > 2.0, lines
    assert (tmp_path / "rb.html").stat().st_size > 10_000
    assert (tmp_path / "rb" / "fit_metrics.json").exists() and (tmp_path / "rb-found" / "model.json").exists()


def test_fit_takes_sessions_or_a_dataset_alike_and_predicts_in_si(session):
    ds = train.load_sessions(session, joints=["joint1", "joint2", "joint4"])
    a = train.fit(ds, "rigid-body", scale_to_data=True, seed=3)
    b = train.fit([session], "rigid-body", scale_to_data=True, seed=3)
    assert a.metrics["test"] == b.metrics["test"]
    pred = a.model.predict(ds.q[:10], ds.dq[:10], ds.ddq[:10])
    assert pred.shape == (10, 3) and np.isfinite(pred).all()


@pytest.mark.parametrize("call, words", [
    (lambda s: train.fit(s, "mlp-mse", effects=["coulomb"], scale_to_data=True),
     "effects apply to rigid-body and hybrid models"),
    (lambda s: train.fit(s, "rigid-body", train_size=10**9, scale_to_data=True), "the training size"),
    (lambda s: train.load_sessions([]), "at least one session"),
    (lambda s: train.load_sessions(s, arm="leader"), "has no /leader group"),
    (lambda s: train.fit(s, "rigid-body", effects=["coulomb:joint"]), "expected key=value"),
])
def test_bad_input_is_one_sentence(session, call, words):
    with pytest.raises(CraneError, match=words) as info:
        call(session)
    assert "\n" not in str(info.value)
    assert isinstance(info.value, (ConfigError, CraneError))


def test_the_report_shows_the_discovery_when_asked(session, tmp_path):
    fitted = train.fit(session, "rigid-body", scale_to_data=True)
    fitted.save(tmp_path / "m")
    plain = train.make_report(tmp_path / "m", session, tmp_path / "plain.html").read_text()
    page = train.make_report(tmp_path / "m", session, tmp_path / "d.html", discover=True).read_text()
    assert "id='discovery'" in page and "id='discovery'" not in plain
