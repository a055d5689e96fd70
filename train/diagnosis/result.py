"""What a diagnosis returns (train/diagnosis/diagnose.py explains the method): one Candidate per effect tried
on a joint, the Diagnosis that holds them ranked with a summary per joint, and the error for data that cannot
support a diagnosis."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from crane_io.errors import CraneError


class DiagnosisError(CraneError):
    """The data cannot support a diagnosis (too few moving samples, a joint that never moves)."""


@dataclass
class Candidate:
    joint: str  # joint name as in the session (for arm-scope effects: the joint where it helps most)
    rank: int  # 1 = best on this joint
    effect: str  # library name
    title: str
    scope: str  # "joint" or "arm"
    error_reduction: float  # fraction of the held-out MSE removed (can be negative: it made things worse)
    fold_reductions: list[float]  # the same, per fold
    folds_improved: int  # folds whose held-out error fell
    # name -> {"value", "std", "unit"}: for a pick of the forward selection after the first, from the model
    # with the earlier picks in (its values alone: parameters_alone)
    parameters: dict[str, dict]
    shape: dict  # chosen shape values (on all data)
    mse_before: float  # held-out MSE of the model's residual on this joint's moving samples, N m^2
    mse_after: float  # the same after adding the candidate
    significant: bool
    sentence: str
    other_joints: dict[str, float] = field(default_factory=dict)  # arm scope: reduction on other joints
    n_parameters: int = 1  # parameters the candidate estimates (linear + shape)
    # spill-over check: set when this candidate was significant alone but no longer is once the
    # strongest significant candidate of another joint is in the model ("coulomb on joint2")
    explained_by: str | None = None
    reduction_given_leader: float | None = None  # its error reduction with that candidate added
    # forward (nested) selection: 1, 2, ... for the candidates put into the model in that order (the
    # significant ones); None for the others
    selection_step: int | None = None
    given: list[str] = field(default_factory=list)  # the effects in the model when it was last judged
    # False: the candidate's columns lie in the span of the model's own parameters (a payload against a
    # fitted rigid-body model): its parameters cannot be estimated and are left out of `parameters`
    identifiable: bool = True
    unidentifiable_parameters: list[str] = field(default_factory=list)
    parameters_alone: dict[str, dict] | None = None  # a later pick's parameters when judged on its own


@dataclass
class Diagnosis:
    joints: tuple[str, ...]
    candidates: list[Candidate]  # ranked per joint (joint order, then rank)
    summary: dict[str, str]  # joint -> one or two sentences
    correlations: dict[str, list[dict]]  # joint -> [{"with": ..., "r": ...}], strongest first
    settings: dict
    # the model's own shape parameters (picked from a grid by `fit`), refined: see train/diagnosis/diagnose.py
    refinements: list[dict] = field(default_factory=list)
    # joint -> [{"with": ..., "share": ...}]: what the residual depends on (held-out binned means)
    dependence: dict[str, list[dict]] = field(default_factory=dict)
    selected: list[str] = field(default_factory=list)  # "coulomb on joint2", ... in selection order

    def for_joint(self, joint: str) -> list[Candidate]:
        return [c for c in self.candidates if c.joint == joint]

    def best(self, joint: str) -> Candidate | None:
        ranked = self.for_joint(joint)
        return ranked[0] if ranked else None

    def to_json(self) -> dict:
        return {"joints": list(self.joints), "candidates": [asdict(c) for c in self.candidates],
                "summary": dict(self.summary), "correlations": self.correlations,
                "settings": self.settings, "selected": list(self.selected),
                "refinements": list(self.refinements), "dependence": self.dependence}
