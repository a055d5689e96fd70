"""What a diagnosis returns (train/diagnose.py explains the method): one Candidate per effect tried on a
joint, the Diagnosis that holds them ranked with a summary per joint, and the error for data that cannot
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
    parameters: dict[str, dict]  # name -> {"value", "std", "unit"}
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


@dataclass
class Diagnosis:
    joints: tuple[str, ...]
    candidates: list[Candidate]  # ranked per joint (joint order, then rank)
    summary: dict[str, str]  # joint -> one or two sentences
    correlations: dict[str, list[dict]]  # joint -> [{"with": ..., "r": ...}], strongest first
    settings: dict

    def for_joint(self, joint: str) -> list[Candidate]:
        return [c for c in self.candidates if c.joint == joint]

    def best(self, joint: str) -> Candidate | None:
        ranked = self.for_joint(joint)
        return ranked[0] if ranked else None

    def to_json(self) -> dict:
        return {"joints": list(self.joints), "candidates": [asdict(c) for c in self.candidates],
                "summary": dict(self.summary), "correlations": self.correlations,
                "settings": self.settings}
