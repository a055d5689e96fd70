"""Learned models for the arms' reaction-force observers (`crane-collect run --model/--leader-model`):
loaded, checked against the arm and the run, and described for the status line and the session.

    models = load_reaction_models({"follower": "models/mlp"}, arm)   # before any torque is on
    ctl = BilateralController(config, arm, models=reaction_factories(models, arm, config))

Every refusal is one sentence (crane_io.physics.loop_model.LoopModelError) raised before the
buses are opened: a missing or damaged model directory, a model without its loop export, units other
than SI, zero-phase preprocessing, joints that are not bilateral joints of this arm, a model fitted on
the other arm's data. Bilateral joints a model does not cover keep the nominal model.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from crane_io import session_format as sf
from crane_io.description import ArmDescription

from .config import Config
from .model_reaction import ModelReaction

ARM_NAMES = ("leader", "follower")


@dataclass
class ArmModel:
    """A learned model in one arm's observer."""

    arm: str  # "leader" or "follower": the arm whose observer uses it
    model: object  # crane_io.physics.loop_model.LoopModel
    limit: np.ndarray  # (J,) N m: larger predictions are not used (the joint's maximum motor torque)

    @property
    def joints(self) -> tuple[str, ...]:
        return tuple(self.model.joint_names)

    def describe(self) -> dict:
        """What the session records about it (root attribute `<arm>_model`, JSON)."""
        m = self.model
        return {"path": str(Path(m.path).resolve()), "method": m.method, "effects": list(m.effects),
                "joints": list(m.joint_names), "fitted_on": m.arm, "sha256": m.sha256,
                "filters": {"cutoff_rad_s": m.preprocessing["cutoff_rad_s"],
                            "pseudo_diff_rad_s": m.preprocessing["pseudo_diff_rad_s"]}}

    def short(self) -> str:
        return f"{self.model.method} ({Path(self.model.path).name}) on {', '.join(self.joints)}"


def load_reaction_models(paths: dict, arm: ArmDescription) -> dict[str, ArmModel]:
    """{arm name: ArmModel} for every arm given a model directory (None or missing: nominal model)."""
    kt = {j.name: j.torque_constant for j in arm.joints}
    out = {}
    for name in ARM_NAMES:
        path = paths.get(name)
        if path is None:
            continue
        from crane_io.physics.loop_model import (
            LoopModel,  # (pinocchio for a rigid-body model: only when asked)
        )

        model = LoopModel.load(path)
        model.check_for_arm(arm.bilateral_joints, name)
        limit = np.array([arm.joint(n).current_limit * kt[n] for n in model.joint_names])
        out[name] = ArmModel(name, model, limit)
    return out


def reaction_factories(models: dict[str, ArmModel], arm: ArmDescription, config: Config) -> dict:
    """{arm name: () -> ModelReaction} for BilateralController(models=...): fresh filter state per reset."""
    rate = config.loop.rate_hz
    for m in models.values():  # the loop's smooth sign of the Coulomb-type terms (0: as fitted)
        if hasattr(m.model, "set_coulomb_velocity"):
            m.model.set_coulomb_velocity(config.controller.model_coulomb_velocity)

    observer = config.controller.model_filters == "observer"

    def factory(m: ArmModel):
        # "observer": one lag at each model joint's observer cutoff g; "training": the model's own filters
        lag = np.array([config.controller.joints[n].cutoff for n in m.joints]) if observer else None
        cutoff = config.controller.model_cutoff or None  # 0: the model's training cutoffs
        own = np.array([config.controller.joints[n].model_cutoff for n in m.joints])
        if own.any():  # per joint: [controller.jointN] model_cutoff where set, else the above, as (w, g)
            pre = m.model.preprocessing
            w = np.where(own > 0, own, cutoff or np.broadcast_to(pre["cutoff_rad_s"], own.shape))
            g = np.where(own > 0, own, cutoff or np.broadcast_to(pre["pseudo_diff_rad_s"], own.shape))
            cutoff = (w, g)
        return lambda: ModelReaction(m.model, arm.joint_names, m.limit, rate, one_lag=lag, cutoff=cutoff)

    return {name: factory(m) for name, m in models.items()}


def observer_sentence(models: dict[str, ArmModel], arm: ArmDescription) -> str:
    """Which joints of each arm use which model, e.g. for the start-up line and the summary."""
    parts = []
    for name in ARM_NAMES:
        m = models.get(name)
        if m is None:
            parts.append(f"{name} nominal")
            continue
        rest = [j for j in arm.bilateral_joints if j not in m.joints]
        text = f"{name} {m.short()}"
        if rest:
            text += f", nominal on {', '.join(rest)}"
        parts.append(text)
    return "reaction-force observers: " + "; ".join(parts)


def session_attrs(models: dict[str, ArmModel]) -> dict:
    """Root attributes `leader_model` and `follower_model`: JSON of the model, or "nominal"."""
    return {sf.model_attr(name): json.dumps(models[name].describe()) if name in models else sf.NOMINAL_MODEL
            for name in ARM_NAMES}

