"""The self-describing model file: named arrays of numbers and a JSON record in one ``.npz``.

Every fitted model the project saves (the Motion Units, the keyframe model, the audio mapping)
is one such file. It holds:

* the model's arrays, each an ``.npy`` member of an uncompressed zip (``np.savez``), numbers
  only (booleans, integers, floats), in their own memory order (a Fortran-ordered array comes
  back Fortran-ordered, so BLAS takes the same path and predictions stay identical to the bit);
* ``metadata``: a 0-d unicode array holding one JSON object, the model's own record plus four
  entries of the file itself: ``kind`` (what the model is, e.g. ``"motion_units"``),
  ``version`` (the kind's format version, a positive integer), ``arrays`` (the manifest:
  every array's dtype and shape) and ``sha256`` (:func:`checksum` of the arrays and the rest of
  the record).

Nothing in the file is code. Reading parses each member's ``.npy`` header before its data and
refuses a member holding Python objects unread; nothing is ever unpickled. Writing is atomic
(:func:`groundwork.atomic.atomic_file`): a crash leaves the previous file or the new one under
the final name, never a part of one.

Files written before this module (the record under ``metadata`` or another member name and no
``kind``) can still be read when the caller names them in ``legacy``; the caller then checks
their record itself, e.g. with :func:`check_arrays`.
"""
from __future__ import annotations

import hashlib
import io
import json
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from groundwork.atomic import atomic_file
from groundwork.errors import ParameterError

METADATA = "metadata"  # the member holding the JSON record
RESERVED = ("kind", "version", "arrays", "sha256")  # the file's own entries of the record
NUMERIC_KINDS = "biuf"  # bool, signed and unsigned integers, floats
ZIP_MAGIC = b"PK\x03\x04"


class ModelFileError(ParameterError):
    """A model file cannot be read: not an ``.npz``, damaged, of another kind or a newer
    version, or holding Python objects. The message is one line naming the file. A
    :class:`~groundwork.errors.ParameterError`, as the loaders raised before."""


@dataclass(frozen=True)
class ModelFile:
    """A model file as read by :func:`read_model`.

    Attributes
    ----------
    path : Path
    kind : str or None
        The file's ``kind``; None for a file written before this format (``legacy``).
    version : int or None
        The kind's format version; None for a file written before this format.
    arrays : dict str → ndarray
        Every array, as stored (dtype, shape and memory order).
    metadata : dict
        The JSON record without the file's own entries (``kind``, ``version``, ``arrays``,
        ``sha256``); for a legacy file, the record as found.
    member : str
        The name of the member the record was read from (``"metadata"`` or a legacy name).
    """

    path: Path
    kind: str | None
    version: int | None
    arrays: dict
    metadata: dict
    member: str = METADATA

    @property
    def legacy(self) -> bool:
        """True for a file written before this format (no kind, version or checksum)."""
        return self.version is None


def checksum(arrays: dict, metadata: dict | None = None) -> str:
    """SHA-256 (hex) of named arrays and, when given, a JSON record.

    Parameters
    ----------
    arrays : dict str → array_like
        Hashed by name: each name, dtype, shape and values in C order (whatever the memory
        layout, so a Fortran-ordered array hashes as its C-ordered copy).
    metadata : dict, optional
        A JSON-able record, hashed as its canonical JSON (sorted keys, no spaces) after the
        arrays. Without it the digest is the audio mapping's format /3 checksum.

    Returns
    -------
    str
        64 hex digits.
    """
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.asarray(arrays[name])
        h.update(json.dumps([name, a.dtype.str, list(a.shape)]).encode() + b"\n")
        h.update(a.tobytes(order="C"))
    if metadata is not None:
        h.update(b"metadata\n" + _canonical(metadata).encode())
    return h.hexdigest()


def _canonical(record: dict) -> str:
    return json.dumps(record, sort_keys=True, separators=(",", ":"))


def manifest(arrays: dict) -> dict:
    """``{name: {"dtype": dtype.str, "shape": [...]}}`` of named arrays, by name."""
    return {n: {"dtype": np.asarray(a).dtype.str, "shape": list(np.shape(a))}
            for n, a in sorted(arrays.items())}


def write_model(path, arrays: dict, metadata: dict, *, kind: str, version: int,
                default=None) -> Path:
    """Write a model file atomically (a temporary file beside ``path``, renamed over it).

    Parameters
    ----------
    path : str or Path
        The file; its folder must exist. Any suffix (``.npz``, ``.tfmap``) is kept as given.
    arrays : dict str → ndarray
        Numeric arrays (bool, int, uint, float) of any shape, stored as they are.
    metadata : dict
        The model's JSON-able record; it may not use the file's own keys ``kind``,
        ``version``, ``arrays``, ``sha256``.
    kind : str
        What the model is, e.g. ``"motion_units"``, ``"keyframes"``, ``"audio_mapping"``.
    version : int
        The kind's format version (≥ 1); :func:`read_model` refuses newer ones.
    default : callable, optional
        ``json.dumps``'s ``default`` for values of ``metadata`` JSON cannot hold.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ParameterError
        Non-numeric arrays, an array named ``metadata``, a reserved key in ``metadata``, a
        bad ``kind`` or ``version``.
    """
    if not isinstance(kind, str) or not kind:
        raise ParameterError(f"a model file's kind must be a non-empty string, got {kind!r}")
    if not isinstance(version, int) or isinstance(version, bool) or version < 1:
        raise ParameterError(f"a model file's version must be a positive integer, got "
                             f"{version!r}")
    taken = [k for k in RESERVED if k in metadata]
    if taken:
        raise ParameterError(f"metadata keys {taken} are the model file's own; rename them")
    arrays = {str(n): np.asarray(a) for n, a in arrays.items()}
    bad = sorted(n for n, a in arrays.items() if a.dtype.kind not in NUMERIC_KINDS)
    if bad or METADATA in arrays:
        raise ParameterError(f"arrays {bad or [METADATA]} cannot be stored: a model file holds "
                             f"numbers only, and {METADATA!r} names its record")
    # the record as it will be read back (tuples as lists, numpy scalars via default), so the
    # checksum is of what the reader sees
    record = json.loads(json.dumps({**metadata, "kind": kind, "version": version,
                                    "arrays": manifest(arrays)}, default=default))
    record["sha256"] = checksum(arrays, record)
    text = json.dumps(record, sort_keys=True)
    path = Path(path)
    with atomic_file(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, allow_pickle=False, **{METADATA: np.array(text)}, **arrays)
    return path


def read_model(path, *, kind: str, versions, what: str = "model file",
               legacy=()) -> ModelFile:
    """Read and check a model file written by :func:`write_model` (or an older one).

    Parameters
    ----------
    path : str or Path
    kind : str
        The kind expected.
    versions : collection of int
        The versions of ``kind`` this code reads; a higher one is "written by a newer version".
    what : str
        The file in messages, after "not a": e.g. ``"Motion Units file"``.
    legacy : tuple of str
        Member names under which files written before this format kept their JSON record
        (e.g. ``("header",)``). A record found under one of them with no ``kind`` is returned
        as it is (``kind`` and ``version`` None), its arrays parsed as safely but not checked
        against it: the caller checks it.

    Returns
    -------
    ModelFile

    Raises
    ------
    ModelFileError
        One line naming the file and the problem: missing; empty, truncated or not a zip;
        a damaged member; a member that is not an ``.npy`` array, is compressed, holds Python
        objects or is not numeric; no record or a record that is not JSON; another kind; an
        unknown or newer version; arrays that disagree with the manifest; a checksum mismatch.
    """
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f"{what} {path} not found")
    text_members = tuple(dict.fromkeys((METADATA, *legacy)))
    members = _members(path, text_members, what)
    found = [n for n in text_members if n in members]
    if not found:
        raise ModelFileError(f"{path}: not a {what} (no {METADATA}; its arrays are "
                             f"{sorted(members)[:5]})")
    if len(found) > 1:
        raise ModelFileError(f"{path}: members {found} each claim to be its record")
    member = found[0]
    record = _record(path, members.pop(member), member, what)
    if "kind" not in record and member in legacy:
        return ModelFile(path, None, None, members, record, member)
    got = record.get("kind")
    if got != kind:
        raise ModelFileError(f"{path}: not a {what} (its kind is {got!r}, expected {kind!r})")
    version = record.get("version")
    if not isinstance(version, int) or isinstance(version, bool) or version < 1:
        raise ModelFileError(f"{path}: not a {what} (its version is {version!r}, not a "
                             "positive integer)")
    if version not in versions:
        if version > max(versions):
            raise ModelFileError(f"{path} was saved by a newer version of talkingface ({kind} "
                                 f"version {version}; this version reads "
                                 f"{_versions_text(versions)}); update talkingface")
        raise ModelFileError(f"{path}: {kind} version {version} is not read by this version "
                             f"of talkingface (it reads {_versions_text(versions)})")
    check_arrays(path, members, record.get("arrays"), record.get("sha256"),
                 metadata={k: v for k, v in record.items() if k != "sha256"}, member=member)
    return ModelFile(path, kind, version, members,
                     {k: v for k, v in record.items() if k not in RESERVED}, member)


def _versions_text(versions) -> str:
    return ", ".join(str(v) for v in sorted(versions))


def check_arrays(path, arrays: dict, listed, sha256, *, metadata: dict | None = None,
                 member: str = METADATA) -> None:
    """Check arrays read from ``path`` against their manifest and checksum.

    Parameters
    ----------
    path : Path
        Named in messages.
    arrays : dict str → ndarray
    listed : dict
        The manifest recorded with them, ``{name: {"dtype", "shape"}}`` as :func:`manifest`
        writes it.
    sha256 : str
        The recorded :func:`checksum` of ``arrays`` (and ``metadata``, if given).
    metadata : dict, optional
        The record the checksum covers besides the arrays (without ``sha256``).
    member : str
        The record's member name, for messages.

    Raises
    ------
    ModelFileError
        No manifest; missing or unlisted arrays; an array whose dtype or shape is not the
        manifest's; a checksum mismatch.
    """
    if not isinstance(listed, dict):
        raise ModelFileError(f"{path}: the {member} has no array manifest")
    missing, extra = sorted(set(listed) - set(arrays)), sorted(set(arrays) - set(listed))
    if missing or extra:
        raise ModelFileError(f"{path}: the arrays do not match the {member} (missing: "
                             f"{missing or 'none'}; not in the {member}: {extra or 'none'})")
    for name, a in sorted(arrays.items()):
        entry = listed[name]
        if not isinstance(entry, dict) or (entry.get("dtype"), entry.get("shape")) != (
                a.dtype.str, list(a.shape)):
            raise ModelFileError(f"{path}: array {name!r} is {a.dtype.str} {a.shape}, the "
                                 f"{member} says {entry!r}")
    digest = checksum(arrays, metadata)
    if digest != sha256:
        raise ModelFileError(f"{path}: checksum mismatch: the file is not the one saved (SHA-256 "
                             f"{digest}, recorded {sha256!r}); the file is damaged")


def _members(path: Path, text_members: tuple, what: str) -> dict:
    """Every member of the zip at ``path`` as an array, each parsed safely."""
    with open(path, "rb") as f:
        start = f.read(len(ZIP_MAGIC))
    if start != ZIP_MAGIC:
        if ZIP_MAGIC.startswith(start):
            raise ModelFileError(f"{path}: not a {what}: the file is empty or truncated "
                                 f"({len(start)} bytes)")
        raise ModelFileError(f"{path}: not a {what} (not an .npz archive)")
    members = {}
    try:
        with zipfile.ZipFile(path) as z:
            for info in z.infolist():
                name = info.filename[:-4] if info.filename.endswith(".npy") else None
                if name is None or name in members:
                    raise ModelFileError(f"{path}: member {info.filename!r} is not one of the "
                                         "model's arrays")
                if info.compress_type != zipfile.ZIP_STORED:  # what np.savez writes; no zip bomb
                    raise ModelFileError(f"{path}: member {info.filename!r} is compressed; "
                                         "model files are written uncompressed")
                members[name] = _parse_npy(path, name, z.read(info), name in text_members)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, NotImplementedError, EOFError, OSError,
            zlib.error) as e:
        raise ModelFileError(f"{path}: the model file is truncated or damaged ({e}); save or "
                             "copy it again") from e
    return members


def _parse_npy(path: Path, name: str, data: bytes, text: bool) -> np.ndarray:
    """One ``.npy`` member: numbers, or one string for the record (``text``). Its dtype is read
    from the ``.npy`` header first; anything holding Python objects is refused unread."""
    buf = io.BytesIO(data)
    try:
        version = np.lib.format.read_magic(buf)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(buf)
        elif version == (2, 0):
            shape, _, dtype = np.lib.format.read_array_header_2_0(buf)
        else:
            raise ValueError(f"unsupported .npy version {version}")
    except ValueError as e:
        raise ModelFileError(f"{path}: member {name!r} is not a numpy array ({e})") from e
    if dtype.hasobject:
        raise ModelFileError(f"{path}: array {name!r} holds pickled Python objects; a model "
                             "file may hold numbers only, so it is not loaded (loading it could "
                             "run code)")
    if dtype.kind not in ("U" if text else NUMERIC_KINDS) or (text and shape != ()):
        raise ModelFileError(f"{path}: array {name!r} has dtype {dtype} {shape}; allowed: "
                             + ("one string" if text else "numbers"))
    size = int(np.prod(shape, dtype=object)) * dtype.itemsize  # Python ints: no overflow
    if size != len(data) - buf.tell():  # checked before read_array allocates the array
        raise ModelFileError(f"{path}: array {name!r} should hold {size} bytes, the file has "
                             f"{len(data) - buf.tell()}; the file is damaged")
    buf.seek(0)
    try:
        return np.lib.format.read_array(buf, allow_pickle=False)
    except ValueError as e:
        raise ModelFileError(f"{path}: array {name!r} is truncated or damaged ({e})") from e


def _record(path: Path, member: np.ndarray, name: str, what: str) -> dict:
    """The JSON object of the record member."""
    try:
        record = json.loads(str(member[()]))
    except (json.JSONDecodeError, RecursionError) as e:
        raise ModelFileError(f"{path}: not a {what} (its {name} is not JSON: {e})") from e
    if not isinstance(record, dict):
        raise ModelFileError(f"{path}: not a {what} (its {name} is not a JSON object)")
    return record
