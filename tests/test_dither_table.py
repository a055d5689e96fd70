"""scripts/dither_table.py, the friction-dither tables of docs/collect.md: every row's configuration is
one the recorder accepts and sets what the row's label says, each ablation variant differs from
docs/examples/dither-model.toml in its one setting, and the table's cells are formatted as the doc's
(a contact error that rounds onto the 10 % goal keeps the digit that tells its side)."""

from __future__ import annotations

import dataclasses
import importlib.util
import sys
from pathlib import Path

import pytest

from collect.config import load_config

ROOT = Path(__file__).resolve().parents[1]
_SPEC = importlib.util.spec_from_file_location("dither_table", ROOT / "scripts" / "dither_table.py")
dt = importlib.util.module_from_spec(_SPEC)
sys.modules.setdefault(_SPEC.name, dt)  # dataclasses look their module up there
_SPEC.loader.exec_module(dt)


def _config(row, tmp_path):
    if row.config is None:
        return load_config()
    path = tmp_path / f"{row.name}.toml"
    path.write_text(row.config)
    return load_config(path)


def _dither(cfg) -> tuple:
    c = cfg.controller
    return (c.dither_amplitude, c.dither_frequency, c.dither_wave, c.dither_filter,
            *(c.joints[j].dither for j in dt.JOINTS))


def test_the_tuning_rows_set_the_dither_their_labels_name(tmp_path):
    got = {(r.label, r.seed): _dither(_config(r, tmp_path)) for r in dt.tuning_rows()}
    assert len(got) == 8 and len({r.name for r in dt.tuning_rows()}) == 8
    p50 = (0.4, 50.0, "sine", True, 1.0, 2.5, 1.0)
    assert list(got.values()) == [
        (0.0, 50.0, "sine", True, 1.0, 1.0, 1.0), (0.4, 50.0, "sine", True, 1.0, 1.0, 1.0),
        (1.0, 20.0, "sine", True, 1.0, 1.0, 1.0), (0.4, 25.0, "sine", True, 1.0, 3.0, 1.0),
        p50, (0.4, 50.0, "sine", True, 1.0, 2.5, 0.0), (0.0, 50.0, "sine", True, 1.0, 1.0, 1.0), p50]
    assert [r.seed for r in dt.tuning_rows()] == [23] * 6 + [29, 29]


def test_each_ablation_variant_changes_only_its_setting(tmp_path):
    shipped = load_config(ROOT / "docs/examples/dither-model.toml")
    rows = dt.ablation_rows()
    assert all(r.model for r in rows)

    def changed(row) -> dict:
        cfg = _config(row, tmp_path)
        assert dataclasses.replace(cfg.controller, joints=shipped.controller.joints) == shipped.controller
        assert dataclasses.replace(cfg, controller=shipped.controller, values=shipped.values) == shipped
        diff = {}
        for joint, gains in cfg.controller.joints.items():
            for f in dataclasses.fields(gains):
                a, b = getattr(gains, f.name), getattr(shipped.controller.joints[joint], f.name)
                if a != b:
                    diff[f"{joint}.{f.name}"] = (b, a)
        return diff

    assert [changed(r) for r in rows] == [
        {}, {"joint1.dither_min_velocity": (0.045, 0.0)}, {},
        {"joint2.model_cutoff": (45.0, 40.0)}, {"joint2.model_cutoff": (45.0, 40.0)}]


def test_a_setting_that_is_not_one_line_of_the_file_is_refused():
    with pytest.raises(SystemExit, match="starts 0 lines"):
        dt._replace_line("a = 1\n", "b =", "b = 2")
    with pytest.raises(SystemExit, match="starts 2 lines"):
        dt._replace_line("a = 1\na = 2\n", "a =", "a = 3")


def _doc(contact, false=(0.02, 0.04, 0.01), end="duration", fallbacks=0):
    joints = {j: {"contact_error_ratio": c, "follower_false_rms": f, "follower_false_rms_still": f / 2,
                  "tracking_rms_deg": 0.25} for j, c, f in zip(dt.JOINTS, (*contact, None), false)}
    return {"joints": joints, "mean_offset": {"joint1": -0.0021, "joint2": 0.0}, "end_reason": end,
            "model_fallback_events": fallbacks}


def test_the_rows_are_formatted_as_the_docs_tables():
    ablation = dt.ablation_table([(dt.ablation_rows()[0], _doc((0.1000134, 0.0789), fallbacks=2))],
                                 {29: _doc((0.2, 0.2), false=(0.1, 0.2, 0.05))})
    assert ablation[2] == ("| as shipped, 29 | 0.0200 / 0.0400 / 0.0100 | 5.00x / 5.00x / 5.00x | "
                           "10.001 % / 7.89 % | 0.25 / 0.25 / 0.25 | duration, 2 model fallbacks |")
    tuning = dt.tuning_table([(r, _doc((0.0996, 0.25))) for r in dt.tuning_rows()[:2]])
    assert tuning[2] == ("| no dither, seed 23 | 9.96% / 25.0% | -0.002 / +0.000 | 0.020 / 0.040 / 0.010 | "
                         "0.010 / 0.020 / 0.005 | 0.25 / 0.25 / 0.25 | duration |")
    assert tuning[3].startswith("| 0.4 N m on every joint, 50 Hz | 9.96% / ")
    assert [dt._percent(r, 1) for r in (0.1000134, 0.1, 0.0994, 0.1000000001, None)] == [
        "10.001", "10.0", "9.9", "10.0000", "-"]
