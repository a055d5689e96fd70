"""What a saved model's numbers must be before anything predicts with them (crane_io.physics.loop_model
reads `loop_model.npz` through these; train.models.model_files uses the same rules for the model's own
files). Each check returns what is wrong as a phrase, or None, so each reader words its own sentence.

* a file is a regular file of at most a bounded size (MAX_FILE_BYTES), readable;
* an .npz is read without pickle, every member an array of numbers or of text (no objects, records or
  raw bytes; the members named in NUMERIC_EXPORT numbers, in TEXT_EXPORT text), its numbers finite and
  at most MAX_ABS in size (larger ones are no fitted value and make a
  prediction overflow);
* a network's scales are usable: input spreads (`x_std`) > 0, output spreads (`y_std`) >= 0;
* the rigid body's locked angles are angles (at most MAX_ANGLE_RAD), its payload a mass of 0 to
  MAX_PAYLOAD_KG;
* the preprocessing record's per-joint lists (`dead_zone_rad_s`, `input_range`) hold one finite number
  per joint (dead zones >= 0, q_min <= q_max).
"""

from __future__ import annotations

import io
import math
import zipfile
from pathlib import Path

import numpy as np

MAX_FILE_BYTES = 512 * 2 ** 20  # no model file is larger (a 7-joint network of 4096 units is ~1 MB)
MAX_ABS = 1e12  # no fitted parameter, weight or scale is larger; 1e308 overflows every prediction
MAX_ANGLE_RAD = 4 * math.pi
MAX_PAYLOAD_KG = 100.0
TEXT_KINDS, NUMBER_KINDS = "U", "iuf"
# export members holding numbers, with their number of dimensions (None: any)
NUMERIC_EXPORT = {"format_version": 0, "mlp_W1": 2, "mlp_b1": 1, "mlp_W2": 2, "mlp_b2": 1, "mlp_x_mean": 1,
                  "mlp_x_std": 1, "mlp_y_mean": 1, "mlp_y_std": 1, "rigid_theta_full": 1,
                  "rigid_locked_angles": None, "rigid_payload_mass": 0, "rigid_effect_coefs": None}
# export members holding text
TEXT_EXPORT = ("method", "joint_names", "units", "source_files", "source_sha256", "rigid_locked_joints",
               "rigid_context_joints")


def file_problem(path: Path, limit: int = MAX_FILE_BYTES) -> str | None:
    """What keeps `path` from being read as a model file (absent, not a regular file, too large), or None."""
    try:
        if not path.is_file():
            return "is missing or not a regular file"
        size = path.stat().st_size
    except OSError as exc:
        return f"cannot be read ({exc.strerror or exc})"
    if size > limit:
        return f"is {size / 2 ** 20:.0f} MB, larger than any model file ({limit / 2 ** 20:.0f} MB at most)"
    return None


def read_bytes(path: Path) -> tuple[bytes | None, str | None]:
    """(the bytes of `path`, None), or (None, what is wrong)."""
    problem = file_problem(path)
    if problem is not None:
        return None, problem
    try:
        return path.read_bytes(), None
    except OSError as exc:
        return None, f"cannot be read ({exc.strerror or exc})"


def npz_arrays(raw: bytes) -> tuple[dict | None, str | None]:
    """Every member of the .npz `raw`, read without pickle: (arrays, None) or (None, what is wrong)."""
    if raw.startswith(b"\x93NUMPY"):
        return None, "is a single array, not an .npz archive of named arrays"
    if not raw.startswith(b"PK"):
        return None, "is corrupt, not a readable numpy .npz file"
    try:
        with np.load(io.BytesIO(raw), allow_pickle=False) as z:
            if not hasattr(z, "files"):
                return None, "is a single array, not an .npz archive of named arrays"
            return {k: z[k] for k in z.files}, None
    except AttributeError:  # a plain .npy has no context manager in older numpy
        return None, "is a single array, not an .npz archive of named arrays"
    except ValueError as exc:
        if "allow_pickle" in str(exc) or "Object arrays" in str(exc):
            return None, "holds Python objects (pickled data), which are never loaded"
        return None, "is corrupt, not a readable numpy .npz file"
    except (OSError, EOFError, zipfile.BadZipFile, KeyError, TypeError, RuntimeError, NotImplementedError,
            MemoryError):  # RuntimeError: a member flagged encrypted; NotImplementedError: an unknown method
        return None, "is corrupt, not a readable numpy .npz file"


def array_problem(name: str, a, ndim: int | None = None, *, text: bool = False) -> str | None:
    """What is wrong with the array `a` stored as `name` (text or numbers, its dimensions, finite and at
    most MAX_ABS), or None."""
    a = np.asarray(a)
    if text:
        if a.dtype.kind not in TEXT_KINDS:
            return f"{name} holds {a.dtype} values, not text"
    else:
        if a.dtype.kind not in NUMBER_KINDS or a.dtype.names:
            return f"{name} holds {a.dtype} values, not numbers"
        if a.size and not np.all(np.isfinite(a)):
            return f"{name} holds NaN or infinite values"
        if a.size and float(np.max(np.abs(a))) > MAX_ABS:
            biggest = float(np.max(np.abs(a)))
            return f"{name} holds a value of {biggest:.3g}, beyond any fitted value ({MAX_ABS:g})"
    if ndim is not None and a.ndim != ndim:
        return f"{name} has shape {a.shape}, not {'a single value' if ndim == 0 else f'{ndim}-dimensional'}"
    return None


def scales_problem(x_std, y_std, what: str = "") -> str | None:
    """A network's standardisation: every input spread > 0, every output spread >= 0."""
    if np.any(np.asarray(x_std, dtype=float) <= 0):
        return f"{what}x_std (the input scales) holds a zero or negative spread"
    if np.any(np.asarray(y_std, dtype=float) < 0):
        return f"{what}y_std (the output scales) holds a negative spread"
    return None


def _member_problem(name: str, a) -> str | None:
    """What is wrong with one member of a loop export as the kind of array its name says, or None."""
    if name in NUMERIC_EXPORT:
        return array_problem(name, a, NUMERIC_EXPORT[name])
    if name in TEXT_EXPORT or np.asarray(a).dtype.kind not in NUMBER_KINDS:
        return array_problem(name, a, text=True)
    return array_problem(name, a)  # a member of numbers this module does not name: finite and bounded


def export_problem(arrays: dict) -> str | None:
    """What is wrong with the members of a loop export (their kinds, finiteness, sizes), or None; which
    members a method needs and how they fit together is loop_model's to check."""
    for name, a in arrays.items():
        problem = _member_problem(name, a)
        if problem is not None:
            return problem
    for name in arrays.get("source_files", np.array([], dtype=str)).ravel().tolist():
        if Path(name).is_absolute() or ".." in Path(name).parts or not name:
            return f"source_files names {name!r}, which is not a file inside the model directory"
    if "mlp_x_std" in arrays and "mlp_y_std" in arrays:
        problem = scales_problem(arrays["mlp_x_std"], arrays["mlp_y_std"], "mlp_")
        if problem is not None:
            return problem
    if "rigid_locked_angles" in arrays and np.any(np.abs(arrays["rigid_locked_angles"]) > MAX_ANGLE_RAD):
        return f"rigid_locked_angles holds an angle beyond {MAX_ANGLE_RAD:.4g} rad"
    if "rigid_payload_mass" in arrays and not 0 <= float(arrays["rigid_payload_mass"]) <= MAX_PAYLOAD_KG:
        mass = float(arrays["rigid_payload_mass"])
        return f"rigid_payload_mass is {mass:g} kg, not 0 to {MAX_PAYLOAD_KG:g}"
    return None


def _numbers(value, n: int) -> bool:
    return (isinstance(value, list) and len(value) == n
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                    and abs(v) <= MAX_ABS for v in value))


def preprocessing_problem(pre: dict, joints: int) -> str | None:
    """What is wrong with the per-joint lists of a model's preprocessing record, or None: `dead_zone_rad_s`
    (one velocity >= 0 per joint) and `input_range` ({"q_min": [...], "q_max": [...]}, one angle each,
    q_min <= q_max), when present."""
    dz = pre.get("dead_zone_rad_s")
    if dz is not None and not (_numbers(dz, joints) and min(dz) >= 0):
        return f"dead_zone_rad_s is {str(dz)[:60]}, not {joints} velocities >= 0 (one per joint)"
    rng = pre.get("input_range")
    if rng is None:
        return None
    if not isinstance(rng, dict) or not _numbers(rng.get("q_min"), joints) or not _numbers(rng.get("q_max"),
                                                                                           joints):
        return f"input_range is {str(rng)[:60]}, not the q_min and q_max of each of the {joints} joints"
    if any(lo > hi for lo, hi in zip(rng["q_min"], rng["q_max"])):
        return "input_range has a q_min above its q_max"
    return None
