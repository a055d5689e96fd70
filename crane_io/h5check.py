"""Name the damage when an HDF5 dataset cannot be read: which dataset, which rows, and whether its
fletcher32 checksum failed (shared by crane-collect recover and crane-train's session reader); and find
damage HDF5 itself does not survive (`damaged_string_heap`).

HDF5 reports a checksum mismatch only as "filter returned failure during read". To say more, every
stored chunk of the dataset is read raw (`read_direct_chunk`, no filters) and its fletcher32 checksum
(the last four bytes of a chunk written with the filter) recomputed here, with HDF5's algorithm.
"""

from __future__ import annotations

import mmap
import struct

import h5py
import numpy as np

from crane_io.errors import SessionDamagedError, SessionFileError

FLETCHER32 = 3  # H5Z_FILTER_FLETCHER32


def _fold(x: int) -> int:
    """HDF5 reduces its sums with end-around carry: 0 stays 0, any other value maps into 1..65535."""
    return 0 if x == 0 else 1 + (x - 1) % 65535


def fletcher32(data: bytes) -> int:
    """HDF5's H5_checksum_fletcher32: big-endian 16-bit words (a last odd byte padded with zero)."""
    raw = np.frombuffer(data, dtype=np.uint8)
    if raw.size % 2:
        raw = np.append(raw, np.uint8(0))
    words = raw.view(">u2").astype(np.uint64)
    n = words.size
    s1 = int(words.sum())
    s2 = int(np.dot(np.arange(n, 0, -1, dtype=np.uint64), words)) if n else 0
    return (_fold(s2) << 16) | _fold(s1)


def chunk_checksum_ok(stored: bytes) -> bool:
    """True if a chunk stored with the fletcher32 filter matches its checksum (HDF5 also accepts the
    byte-swapped form written by versions before 1.6.3)."""
    if len(stored) < 4:
        return False
    body, tail = stored[:-4], stored[-4:]
    kept = int.from_bytes(tail, "little")
    swapped = (tail[1] << 24) | (tail[0] << 16) | (tail[3] << 8) | tail[2]
    return fletcher32(body) in (kept, swapped)


def has_fletcher32(ds: h5py.Dataset) -> bool:
    plist = ds.id.get_create_plist()
    return any(plist.get_filter(i)[0] == FLETCHER32 for i in range(plist.get_nfilters()))


def bad_checksum_rows(ds: h5py.Dataset) -> list[tuple[int, int]]:
    """(first, last) rows of every stored chunk of `ds` whose fletcher32 checksum fails (empty when
    the dataset has no such filter or all chunks match)."""
    if ds.chunks is None or not has_fletcher32(ds):
        return []
    out = []
    rows = ds.chunks[0] if ds.ndim else 1
    for i in range(ds.id.get_num_chunks()):
        info = ds.id.get_chunk_info(i)
        try:
            _, stored = ds.id.read_direct_chunk(info.chunk_offset)
        except OSError:
            stored = b""
        if not chunk_checksum_ok(stored):
            start = info.chunk_offset[0] if ds.ndim else 0
            out.append((start, min(start + rows, ds.shape[0] if ds.ndim else 1) - 1))
    return out


def damaged_dataset(path, ds: h5py.Dataset, exc: Exception) -> SessionDamagedError:
    """The one sentence for a dataset whose read failed with HDF5's OSError `exc`."""
    try:
        bad = bad_checksum_rows(ds)
    except (OSError, ValueError, AttributeError):
        bad = []
    if bad:
        spans = ", ".join(f"{a}-{b}" for a, b in bad[:3])
        spans += f" and {len(bad) - 3} more chunks" if len(bad) > 3 else ""
        what = f"fails its fletcher32 checksum in rows {spans}"
        salvage = f", or `crane-collect recover {path} -o NEW.h5` to keep every row that passes its checksum"
    else:
        what = f"cannot be read ({exc})"
        salvage = ""
    return SessionDamagedError(f"{path}: dataset {ds.name} {what}, so the file is damaged (a disk or copy "
                               f"error); use another copy of the session{salvage}")


# -- members reached without leaving the file --------------------------------------------------------------
MAX_SOFT_LINKS = 16  # soft links followed on the way to one member; more is a loop


def _hop(path, group: h5py.Group, name: str, where: str, hops: list):
    """The object `name` (one path component) of `group`, following soft links inside the file only;
    None when there is nothing of that name. `where` is the member's full name, for the sentence."""
    try:
        link = group.get(name, getlink=True)
    except (KeyError, ValueError, OSError, RuntimeError, TypeError):
        raise SessionFileError(f"{path}: the link /{where} cannot be read, so the file is damaged or not "
                               f"a plain HDF5 file") from None
    if link is None:
        return None
    if isinstance(link, h5py.ExternalLink):
        raise SessionFileError(f"{path}: /{where} is an external link to {link.filename}:{link.path}; "
                               f"a file is read from itself only, so it is refused")
    if isinstance(link, h5py.SoftLink):
        hops.append(link.path)
        if len(hops) > MAX_SOFT_LINKS:
            raise SessionFileError(f"{path}: /{where} is a soft link that leads into a loop of links "
                                   f"({' -> '.join(hops[:4])} ...), so it names nothing")
        root = group.file if link.path.startswith("/") else group
        target = _walk(path, root, link.path, where, hops)
        if target is None:
            raise SessionFileError(f"{path}: /{where} is a soft link to {link.path}, which does not exist")
        return target
    if not isinstance(link, h5py.HardLink):
        raise SessionFileError(f"{path}: /{where} is a link of a kind this reader does not follow")
    try:
        return group[name]
    except (KeyError, ValueError, OSError, RuntimeError, TypeError):
        raise SessionFileError(f"{path}: /{where} cannot be opened, so the file is damaged") from None


def _walk(path, start: h5py.Group, name: str, where: str, hops: list):
    obj = start
    parts = [p for p in name.split("/") if p and p != "."]
    for i, part in enumerate(parts):
        if not isinstance(obj, h5py.Group):
            shown = "/".join(parts[:i])
            raise SessionFileError(f"{path}: /{shown} is a {kind_of(obj)}, not a group, so /{where} cannot "
                                   f"be in it")
        obj = _hop(path, obj, part, where, hops)
        if obj is None:
            return None
    return obj


def kind_of(obj) -> str:
    """"group", "dataset" or "named datatype": what an HDF5 object is, for a sentence."""
    if isinstance(obj, h5py.Group):
        return "group"
    if isinstance(obj, h5py.Dataset):
        return "dataset"
    return "named datatype" if isinstance(obj, h5py.Datatype) else type(obj).__name__


def member(path, f: h5py.File, name: str, kind: type = h5py.Dataset):
    """The object `name` ("follower/q") of the open file `f`, or None when the file has nothing there.

    Soft links inside the file are followed (a dangling one or a loop is a SessionFileError); an
    external link, a virtual dataset or a dataset stored in external files would read another file and
    is refused, as is an object that is not a `kind` (h5py.Dataset or h5py.Group)."""
    obj = _walk(path, f, name, name.strip("/"), [])
    if obj is None:
        return None
    if not isinstance(obj, kind):
        want = "dataset" if kind is h5py.Dataset else "group"
        raise SessionFileError(f"{path}: /{name.strip('/')} is a {kind_of(obj)}, not a {want}")
    if isinstance(obj, h5py.Dataset):
        try:
            outside = obj.is_virtual or bool(obj.external)
        except (OSError, ValueError, RuntimeError):
            outside = True
        if outside:
            raise SessionFileError(f"{path}: /{name.strip('/')} keeps its data in other files (a virtual or "
                                   f"external dataset); a file is read from itself only, so it is refused")
    return obj


def missing_filter(ds: h5py.Dataset) -> str | None:
    """The name or number of a filter `ds` was written with that this installation's HDF5 lacks, or None."""
    try:
        plist = ds.id.get_create_plist()
        for i in range(plist.get_nfilters()):
            code, _, _, name = plist.get_filter(i)
            if not h5py.h5z.filter_avail(code):
                text = name.decode("ascii", "replace") if isinstance(name, bytes) else str(name)
                return text or str(code)
    except (OSError, ValueError, RuntimeError):
        return None
    return None


GCOL = b"GCOL"  # the signature of an HDF5 global heap collection (variable-length strings live there)
_GCOL_HEADER = struct.Struct("<4sB3sQ")  # signature, version 1, reserved, collection size (with header)
_GCOL_OBJECT = struct.Struct("<HH4sQ")  # heap object index (0: free space), reference count, reserved, size


def damaged_string_heap(path) -> str | None:
    """A sentence naming the damage when a global heap collection of the HDF5 file `path` is not
    self-consistent (a collection longer than the file, an object that runs past its collection), else
    None. HDF5 reads such an object's claimed length before it looks at it: a bit flipped in a size field
    makes a string attribute's read hang or take all the memory, so this is checked before any string is
    read (HDF5 file format specification, version 2, section III.E "Global Heap")."""
    with open(path, "rb") as fh:
        size = fh.seek(0, 2)
        if size < _GCOL_HEADER.size:
            return None
        with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as raw:
            at = raw.find(GCOL)
            while at >= 0:
                problem = _collection_problem(raw, at, size)
                if problem:
                    return f"its string storage (the HDF5 global heap at byte {at}) is damaged: {problem}"
                at = raw.find(GCOL, at + 1)
    return None


def _collection_problem(raw, at: int, size: int) -> str | None:
    if at + _GCOL_HEADER.size > size:
        return None
    _, version, reserved, length = _GCOL_HEADER.unpack_from(raw, at)
    if version != 1 or reserved != bytes(3):
        return None  # the four letters inside other data, not a collection
    end = at + length
    if length < _GCOL_HEADER.size or end > size:
        return f"a collection of {length} bytes where at most {size - at} remain"
    j = at + _GCOL_HEADER.size
    while j + _GCOL_OBJECT.size <= end:
        index, _, _, obj = _GCOL_OBJECT.unpack_from(raw, j)
        if index == 0:  # the free space closes the collection: it is all the bytes that are left
            return None if obj == end - j else (f"its free space says {obj} bytes where {end - j} are "
                                                f"left, so an object before it has the wrong size")
        if obj > end - j - _GCOL_OBJECT.size:
            return f"an object of {obj} bytes in a collection with {end - j - _GCOL_OBJECT.size} left"
        j += _GCOL_OBJECT.size + (obj + 7) // 8 * 8
    return None if j <= end else "its last object runs past the collection"
