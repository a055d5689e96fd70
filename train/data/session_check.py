"""What the session readers check before they use a file (train.data.session, train.replay,
train.evaluation.fidelity), each refusal one sentence naming the file and the attribute or dataset:

* every root attribute can be read; the required ones have their declared kinds (crane_io.session_format:
  `format` a string, `format_version` an integer this reader knows, `rate_hz` a finite number of Hz > 0
  and at most MAX_RATE_HZ, `joint_names` distinct printable strings, `source` a printable string); an
  optional attribute that is present has its declared kind (a string, an integer, a number, a flag, or
  an array of them);
* every member is reached without leaving the file (crane_io.h5check.member: no external link, virtual
  or external dataset; a dangling soft link or a loop of them is named) and is what the format says: a
  group where a group belongs, a dataset of numbers (integers or floats: no strings, objects, compounds,
  flags) of shape (N,) or (N, J) with J the number of `joint_names`;
* rate_hz agrees with the time steps of `t` (within a factor RATE_TOLERANCE);
* what is read fits in memory (at most half of this computer's, MAX_MEMORY_FRACTION), and rows that
  cannot be decoded (a failing checksum, a filter this installation lacks) are named.

Files are only ever opened read-only.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

import h5py
import numpy as np

from crane_io.errors import SessionFileError
from crane_io.h5check import damaged_dataset, damaged_string_heap, member, missing_filter
from crane_io.session_format import (
    EXCITATION_ROOT,
    FORMAT_ATTR,
    IMPORT_ROOT,
    JOINT_NAMES_ATTR,
    OPTIONAL_ROOT,
    RATE_ATTR,
    SOURCE_ATTR,
)

MAX_RATE_HZ = 1e6  # no recording is sampled faster; a larger rate_hz is nonsense
MAX_NAME_CHARS = 64  # a joint name longer than this is no joint name
MAX_MEMORY_FRACTION = 0.5  # what one read may take of this computer's memory
RATE_TOLERANCE = 2.0  # rate_hz and the median step of t agree within this factor
NUMBER_KINDS = "fiu"  # numpy dtype kinds a signal may be stored as: float, signed and unsigned integer
DECLARED = {a.name: a.kind for a in OPTIONAL_ROOT + IMPORT_ROOT + EXCITATION_ROOT}



_TRUNCATED = re.compile(r"truncated file: eof = (?P<eof>\d+).*stored_eof = (?P<stored>\d+)")


def open_checked(path: Path, what: str, kind: str) -> h5py.File:
    """The HDF5 file at `path` opened read-only for a reader of `what` ("session file", "truth trace"),
    or one sentence (SessionFileError): missing, not a file, unreadable, not HDF5 (so it cannot be
    `kind`), cut off, or its string storage damaged. A plain read comes first: it checks the file's
    length against its header, which an SWMR read skips (a cut-off copy read in SWMR mode makes HDF5
    retry its checksums for many minutes). A recording still being written, or one whose writer
    crashed, refuses the plain read and is read in SWMR mode. The global heap is checked before any
    string is read: HDF5 hangs on some damage there (crane_io.h5check.damaged_string_heap)."""
    if not path.exists():
        raise SessionFileError(f"{what} {path} does not exist")
    if not path.is_file():
        raise SessionFileError(f"{path} is not a file")
    try:
        with open(path, "rb") as fh:
            fh.read(8)
    except OSError as exc:
        raise SessionFileError(f"{path} cannot be read ({exc.strerror or exc})") from None
    if not h5py.is_hdf5(str(path)):
        raise SessionFileError(f"{path} is not an HDF5 file, so it cannot be {kind}")
    f = _open_hdf5(path)
    heap = damaged_string_heap(path)
    if heap:
        f.close()
        raise SessionFileError(f"{path} cannot be read: {heap}")
    return f


def _open_hdf5(path: Path) -> h5py.File:
    try:
        return h5py.File(str(path), "r")
    except (OSError, RuntimeError, ValueError) as exc:
        cut = _TRUNCATED.search(str(exc))
        if cut:
            raise SessionFileError(f"{path} is cut off: it has {int(cut['eof'])} bytes but its HDF5 header "
                                   f"says {int(cut['stored'])} (an incomplete copy or download); copy it "
                                   f"again") from None
    try:
        return h5py.File(str(path), "r", swmr=True)
    except (OSError, RuntimeError, ValueError) as exc:
        raise SessionFileError(f"{path} cannot be opened as HDF5 ({exc})") from None


def decode(value):
    """An attribute as plain Python: str for strings (UTF-8, undecodable bytes replaced), int/float/bool for
    scalars, a list for an array; anything else (an empty attribute, a reference) as h5py returns it."""
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "SO":
            return [decode(v) for v in value.tolist()]
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def read_attrs(path, obj) -> dict:
    """Every attribute of `obj` (the file's root or a group), decoded; one that cannot be read (a type
    h5py does not know, damaged storage) is a SessionFileError naming it."""
    out = {}
    try:
        names = list(obj.attrs.keys())
    except (OSError, RuntimeError, ValueError, TypeError, KeyError):
        raise SessionFileError(f"{path}: the attributes of {obj.name} cannot be read, so the file is "
                               f"damaged") from None
    limit = _file_bytes(path, obj)
    for name in names:
        try:
            stored = obj.attrs.get_id(name)
            if _elements(stored.shape) * max(stored.dtype.itemsize, 1) > limit:
                raise ValueError("an attribute larger than its file")  # a damaged dataspace; never read
            out[name] = decode(obj.attrs[name])
        except (OSError, RuntimeError, ValueError, TypeError, KeyError):
            raise SessionFileError(f"{path}: the attribute {name!r} of {obj.name} cannot be read (damaged, "
                                   f"or of a type this reader does not know)") from None
    return out


def _file_bytes(path, obj) -> int:
    """The size of the file `obj` lives in: no attribute's stored value can be larger (a damaged
    dataspace can claim billions of elements, which h5py would allocate before reading)."""
    try:
        return os.path.getsize(obj.file.filename)
    except (OSError, ValueError, TypeError):
        return os.path.getsize(path)


def _elements(shape) -> int:
    """Elements of an attribute's shape (None: an empty attribute; (): a scalar), as an exact int."""
    if shape is None:
        return 0
    return math.prod(int(d) for d in shape)


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _is_printable(v) -> bool:
    return isinstance(v, str) and v.isprintable()


def _shown(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def check_rate(path, attrs: dict) -> float:
    """The root attribute rate_hz: a finite number of Hz, > 0 and at most MAX_RATE_HZ."""
    value = attrs[RATE_ATTR]
    if not _is_number(value) or not math.isfinite(value) or not 0 < value <= MAX_RATE_HZ:
        raise SessionFileError(f"{path} has an invalid {RATE_ATTR} {_shown(value)}; it must be the sampling "
                               f"rate in Hz, a number above 0 and at most {MAX_RATE_HZ:g}")
    return float(value)


def check_joint_names(path, attrs: dict, attr: str = JOINT_NAMES_ATTR) -> tuple[str, ...]:
    """The root attribute joint_names: one or more distinct, printable, non-empty strings."""
    value = attrs[attr]
    names = (value,) if isinstance(value, str) else tuple(value) if isinstance(value, list) else None
    if not names or not all(_is_printable(n) and 0 < len(n) <= MAX_NAME_CHARS for n in names):
        raise SessionFileError(f"{path} has an invalid {attr} {_shown(value)}; it must be an array of joint "
                               f"names (printable strings of 1 to {MAX_NAME_CHARS} characters)")
    if len(set(names)) != len(names):
        twice = next(n for n in names if names.count(n) > 1)
        raise SessionFileError(f"{path} names the joint {twice} twice in {attr}")
    return names


def check_source(path, attrs: dict) -> str:
    """The root attribute source: a printable string."""
    value = attrs[SOURCE_ATTR]
    if not _is_printable(value):
        raise SessionFileError(f"{path} has an invalid {SOURCE_ATTR} {_shown(value)}; it must be a word "
                               f"naming the rig (a printable string)")
    return value


def check_format_attr(path, attrs: dict, expected: str, called: str = "") -> None:
    """The root attribute format must be `expected`; `called`: what such a file is called ("a truth
    trace"; default "a EXPECTED file")."""
    fmt = attrs.get(FORMAT_ATTR)
    if fmt != expected:
        what = "has no 'format' attribute" if fmt is None else f"has format {_shown(fmt)}"
        raise SessionFileError(f"{path} is not {called or f'a {expected} file'} (it {what})")


def _kind_ok(value, kind: str) -> bool:
    base = kind.split()[0]
    test = {"str": lambda v: isinstance(v, str), "int": _is_int, "float": _is_number,
            "bool": lambda v: isinstance(v, bool) or v in (0, 1) and _is_int(v)}.get(base)
    if test is None:
        return True
    if "array" in kind or "(J,)" in kind:
        return test(value) or (isinstance(value, list) and all(test(v) for v in value))
    return test(value)


def check_declared(path, attrs: dict) -> None:
    """Every optional root attribute that is present has its declared kind (crane_io.session_format)."""
    for name, kind in DECLARED.items():
        if name in attrs and not _kind_ok(attrs[name], kind):
            raise SessionFileError(f"{path} has the attribute {name} = {_shown(attrs[name])}, which is not "
                                   f"of its kind ({kind})")


def dataset(path, f: h5py.File, name: str, joints: int | None = None, required: bool = True):
    """The dataset `name` of `f` checked to hold numbers of shape (N,) (`joints` None) or (N, joints);
    None when it is absent and not `required`."""
    ds = member(path, f, name, h5py.Dataset)
    if ds is None:
        if required:
            raise SessionFileError(f"{path} lacks the required dataset /{name}")
        return None
    try:
        dtype, shape = ds.dtype, ds.shape
    except (OSError, RuntimeError, ValueError, TypeError):
        raise SessionFileError(f"{path}: /{name} cannot be read (its type or shape is damaged)") from None
    if dtype.kind not in NUMBER_KINDS or dtype.subdtype is not None or dtype.names:
        raise SessionFileError(f"{path}: /{name} holds {_dtype_words(dtype)}, not numbers")
    want = "(N,)" if joints is None else f"(N, {joints})"
    ndim = 1 if joints is None else 2
    if shape is None or len(shape) != ndim or (joints is not None and shape[1] != joints):
        shown = "no shape (an empty dataset)" if shape is None else f"shape {shape}"
        extra = "" if joints is None else f" to match the {joints} joint_names"
        raise SessionFileError(f"{path}: /{name} has {shown}, expected {want}{extra}")
    return ds


def _dtype_words(dtype: np.dtype) -> str:
    if dtype.names:
        return "records (a compound type)"
    return {"S": "byte strings", "U": "strings", "O": "objects or variable-length strings", "b": "flags",
            "c": "complex numbers", "V": "raw or array-typed values", "M": "dates", "m": "time spans"}.get(
        dtype.kind, f"values of type {dtype}")


def memory_bytes() -> int:
    """This computer's memory in bytes (0 when unknown)."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return 0


def check_fits(path, name: str, rows: int, columns: int, arrays: int = 1) -> None:
    """Reading `arrays` float64 arrays of (rows, columns) must fit in MAX_MEMORY_FRACTION of the memory."""
    need = 8 * rows * max(columns, 1) * arrays
    have = memory_bytes()
    if have and need > MAX_MEMORY_FRACTION * have:
        raise SessionFileError(f"{path}: /{name} holds {rows} rows ({need / 1e9:.1f} GB as numbers), more "
                               f"than this computer's memory can read; cut the recording into shorter files")


def check_rate_matches(path, arm: str, t: np.ndarray, rate_hz: float) -> None:
    """rate_hz must agree with the median time step of `t` within RATE_TOLERANCE (a recording's
    late cycles make some steps longer, never the median by this much)."""
    if len(t) < 2:
        return
    step = float(np.median(np.diff(t)))
    if not RATE_TOLERANCE ** -1 <= step * rate_hz <= RATE_TOLERANCE:
        raise SessionFileError(f"{path} has {RATE_ATTR} {rate_hz:g} Hz but its /{arm}/t advances by "
                               f"{step:.6g} s a sample (a rate of {1 / step:.6g} Hz), so one of them is "
                               f"wrong")


def read_rows(path, ds: h5py.Dataset, n: int) -> np.ndarray:
    """The first n rows of a checked dataset as float64; a chunk failing its fletcher32 checksum, a filter
    this installation lacks or storage that cannot be decoded is one sentence naming the dataset."""
    check_fits(path, ds.name.lstrip("/"), n, int(np.prod(ds.shape[1:], dtype=np.int64)) if ds.ndim else 1)
    try:
        return np.asarray(ds[:n], dtype=float)
    except OSError as exc:
        absent = missing_filter(ds)
        if absent:
            raise SessionFileError(f"{path}: {ds.name} is compressed with the filter {absent}, which this "
                                   f"installation's HDF5 lacks, so it cannot be read") from None
        raise damaged_dataset(path, ds, exc) from None
    except (ValueError, TypeError, RuntimeError):
        raise SessionFileError(f"{path}: {ds.name} cannot be read as numbers, so the file is "
                               f"damaged") from None
    except MemoryError:
        raise SessionFileError(f"{path}: {ds.name} is too large to read into this computer's "
                               f"memory") from None
