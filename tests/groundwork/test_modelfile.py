"""The model file (groundwork.modelfile): arrays and metadata come back exactly, writing is
atomic, and every damaged, foreign, newer or pickled file is refused in one line naming it,
without running anything in it."""
from __future__ import annotations

import io
import json
import math
import pickle
import re
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays as array_strategy
from hypothesis.extra.numpy import scalar_dtypes

from groundwork import modelfile
from groundwork.errors import ParameterError
from groundwork.modelfile import ModelFileError, read_model, write_model

KIND = "test_model"


def _arrays() -> dict:
    rng = np.random.default_rng(3)
    return {"w": rng.standard_normal((4, 3)),
            "w_fortran": np.asfortranarray(rng.standard_normal((3, 5)).astype(np.float32)),
            "counts": np.arange(6, dtype=np.int64).reshape(2, 3),
            "bytes": np.array([0, 255, 7], dtype=np.uint8),
            "mask": np.array([True, False, True]),
            "scalar": np.array(2.5),
            "empty": np.zeros((0, 3)),
            "part/nested/name": np.array([-0.0, 1e-300, np.inf, np.nan])}


META = {"sample_rate": 22050, "third": 1 / 3, "tiny": 2.0**-1074, "text": "naïve — 顔",
        "nested": {"list": [1, 2.5, None, True], "empty": {}}, "negative_zero": -0.0}


def _read(path, **kw):
    return read_model(path, **{"kind": KIND, "versions": (1, 2), "what": "test model",
                               **kw})


def _one_line(excinfo) -> str:
    text = str(excinfo.value)
    assert "\n" not in text and isinstance(excinfo.value, ParameterError)
    return text


@pytest.fixture
def saved(tmp_path) -> Path:
    return write_model(tmp_path / "model.tfmap", _arrays(), META, kind=KIND, version=2)


def _members(path) -> dict:
    with zipfile.ZipFile(path) as z:
        return {i.filename: z.read(i) for i in z.infolist()}


def _zip(path, members: dict) -> Path:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as z:
        for name, data in members.items():
            z.writestr(name, data)
    return path


def _npy(a, allow_pickle=False) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a, allow_pickle=allow_pickle)
    return buf.getvalue()


def _edit_record(path, out, edit, *, reseal: bool) -> Path:
    """A copy of ``path`` with its JSON record edited (and its checksum made to fit, if
    ``reseal``)."""
    members = _members(path)
    record = json.loads(str(np.load(io.BytesIO(members["metadata.npy"]))[()]))
    edit(record)
    if reseal:
        with np.load(path) as z:
            arrays = {n: z[n] for n in z.files if n != "metadata"}
        del record["sha256"]
        record["sha256"] = modelfile.checksum(arrays, record)
    members["metadata.npy"] = _npy(np.array(json.dumps(record)))
    return _zip(out, members)


class Touch:
    """Unpickling this creates the file ``marker`` (a stand-in for arbitrary code)."""

    def __init__(self, marker):
        self.marker = Path(marker)

    def __reduce__(self):
        return Path.touch, (self.marker,)


# -- round trips ---------------------------------------------------------------------------------

def test_arrays_and_metadata_come_back_exactly(saved):
    found = _read(saved)
    assert (found.kind, found.version, found.member, found.legacy) == (KIND, 2, "metadata", False)
    assert found.path == saved
    original = _arrays()
    assert sorted(found.arrays) == sorted(original)
    for name, a in original.items():
        b = found.arrays[name]
        assert (b.dtype, b.shape, b.tobytes(order="A")) == (a.dtype, a.shape, a.tobytes(order="A"))
        assert b.flags.f_contiguous == a.flags.f_contiguous  # memory order kept: same BLAS path
    assert found.metadata == META
    assert math.copysign(1, found.metadata["negative_zero"]) == -1
    assert found.metadata["tiny"] == 5e-324 and found.metadata["third"] == 1 / 3


def test_the_file_is_numbers_and_one_json_record(saved):
    with np.load(saved, allow_pickle=False) as z:
        record = json.loads(str(z["metadata"]))
        assert z["metadata"].dtype.kind == "U" and z["metadata"].shape == ()
        assert {z[n].dtype.kind for n in z.files if n != "metadata"} <= set("biuf")
    assert (record["kind"], record["version"]) == (KIND, 2)
    assert record["arrays"] == modelfile.manifest(_arrays())
    assert record["arrays"]["w_fortran"] == {"dtype": "<f4", "shape": [3, 5]}
    rest = {k: v for k, v in record.items() if k != "sha256"}
    assert record["sha256"] == modelfile.checksum(_arrays(), rest)
    assert {k: v for k, v in rest.items() if k not in modelfile.RESERVED} == META
    with zipfile.ZipFile(saved) as z:
        assert all(i.compress_type == zipfile.ZIP_STORED for i in z.infolist())


def test_the_checksum_is_of_values_not_of_memory_order():
    a = np.arange(12.0).reshape(3, 4)
    assert modelfile.checksum({"a": a}) == modelfile.checksum({"a": np.asfortranarray(a)})
    assert modelfile.checksum({"a": a}) != modelfile.checksum({"a": a.T.copy()})
    assert modelfile.checksum({"a": a}) != modelfile.checksum({"b": a})
    assert modelfile.checksum({"a": a}, {"x": 1}) != modelfile.checksum({"a": a}, {"x": 2})
    assert len(modelfile.checksum({})) == 64


def test_numpy_values_in_the_metadata_are_written_with_default(tmp_path):
    path = write_model(tmp_path / "m.npz", {}, {"n": np.int64(3), "v": np.arange(2)},
                       kind=KIND, version=1,
                       default=lambda o: o.item() if np.ndim(o) == 0 else o.tolist())
    assert _read(path).metadata == {"n": 3, "v": [0, 1]}


@settings(max_examples=30, deadline=None)
@given(a=array_strategy(scalar_dtypes().filter(lambda d: d.kind in "biuf"),
                        st.tuples(st.integers(0, 3), st.integers(0, 4))),
       meta=st.dictionaries(st.text(max_size=5).filter(lambda k: k not in modelfile.RESERVED),
                            st.integers() | st.text(max_size=8) | st.booleans() | st.none()
                            | st.floats(allow_nan=False), max_size=4))
def test_any_numeric_array_and_json_record_round_trip(tmp_path_factory, a, meta):
    path = write_model(tmp_path_factory.mktemp("h") / "m.npz", {"a": a}, meta, kind=KIND,
                       version=1)
    found = _read(path)
    b = found.arrays["a"]
    assert (b.dtype, b.shape, b.tobytes()) == (a.dtype, a.shape, a.tobytes())
    assert found.metadata == meta


# -- writing -------------------------------------------------------------------------------------

def test_a_failed_write_leaves_the_previous_file_and_nothing_else(saved, monkeypatch):
    before = saved.read_bytes()

    def savez_then_fail(f, **arrays):  # half a file written, then the disk is full
        f.write(b"PK\x03\x04 half a model")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(modelfile.np, "savez", savez_then_fail)
    with pytest.raises(OSError, match="No space left"):
        write_model(saved, {"x": np.zeros(3)}, {}, kind=KIND, version=2)
    assert saved.read_bytes() == before
    assert [p.name for p in saved.parent.iterdir()] == [saved.name]
    fresh = saved.parent / "fresh.tfmap"
    with pytest.raises(OSError, match="No space left"):
        write_model(fresh, {"x": np.zeros(3)}, {}, kind=KIND, version=2)
    assert [p.name for p in saved.parent.iterdir()] == [saved.name]  # no file under its name


def test_writing_over_a_model_replaces_it_whole(saved):
    write_model(saved, {"x": np.ones(2)}, {"note": "second"}, kind=KIND, version=1)
    found = _read(saved)
    assert list(found.arrays) == ["x"] and found.metadata == {"note": "second"}
    assert found.version == 1
    assert [p.name for p in saved.parent.iterdir()] == [saved.name]


@pytest.mark.parametrize("arrays, meta, kw, message", [
    ({"x": np.array(["a", "b"])}, {}, {}, r"arrays \['x'\] cannot be stored: a model file holds "
                                          r"numbers only, and 'metadata' names its record"),
    ({"x": np.array([None], dtype=object)}, {}, {}, r"arrays \['x'\] cannot be stored: .*"),
    ({"metadata": np.zeros(2)}, {}, {}, r"arrays \['metadata'\] cannot be stored: .*"),
    ({}, {"sha256": "x", "kind": "y"}, {}, r"metadata keys \['kind', 'sha256'\] are the model "
                                            r"file's own; rename them"),
    ({}, {}, {"kind": ""}, r"a model file's kind must be a non-empty string, got ''"),
    ({}, {}, {"version": 0}, r"a model file's version must be a positive integer, got 0"),
    ({}, {}, {"version": True}, r"a model file's version must be a positive integer, got True"),
], ids=["strings", "objects", "name", "reserved", "kind", "version", "bool-version"])
def test_what_cannot_be_written_is_refused_before_the_file_is_touched(saved, arrays, meta, kw,
                                                                      message):
    before = saved.read_bytes()
    with pytest.raises(ParameterError, match="^" + message + "$"):
        write_model(saved, arrays, meta, **{"kind": KIND, "version": 1, **kw})
    assert saved.read_bytes() == before


# -- refusals ------------------------------------------------------------------------------------

def test_missing_empty_truncated_and_foreign_files(saved, tmp_path):
    p = re.escape(str(tmp_path))
    with pytest.raises(ModelFileError, match=f"^test model {p}/nothere.npz not found$"):
        _read(tmp_path / "nothere.npz")
    with pytest.raises(ModelFileError, match=f"^test model {p} not found$"):
        _read(tmp_path)  # a folder
    blob = saved.read_bytes()
    for name, data, message in [
            ("empty", b"", r"not a test model: the file is empty or truncated \(0 bytes\)"),
            ("two", blob[:2], r"not a test model: the file is empty or truncated \(2 bytes\)"),
            ("text", b"not a model\n", r"not a test model \(not an \.npz archive\)"),
            ("pickle", pickle.dumps({"w": [1, 2]}), r"not a test model \(not an \.npz archive\)"),
            ("cut", blob[: len(blob) // 2], r"the model file is truncated or damaged \(.*\); "
                                            r"save or copy it again"),
            ("tail", blob[:-1], r"the model file is truncated or damaged \(.*\); save or "
                                r"copy it again")]:
        path = tmp_path / f"{name}.tfmap"
        path.write_bytes(data)
        with pytest.raises(ModelFileError, match=f"^{re.escape(str(path))}: {message}$") as e:
            _read(path)
        _one_line(e)


def test_every_truncation_is_one_line_naming_the_file(saved, tmp_path):
    blob = saved.read_bytes()
    for cut in range(0, len(blob), max(1, len(blob) // 60)):
        path = tmp_path / f"cut{cut}.tfmap"
        path.write_bytes(blob[:cut])
        with pytest.raises(ModelFileError, match=f"^{re.escape(str(path))}: ") as e:
            _read(path)
        _one_line(e)


def test_a_flipped_byte_is_found(saved, tmp_path):
    """In the archive, zip's CRC of the member catches it; in a consistent archive (the zip
    rewritten around the changed bytes), the SHA-256 does; in the record too."""
    blob = bytearray(saved.read_bytes())
    at = bytes(blob).find(_arrays()["w"].tobytes()) + 3
    blob[at] ^= 0x10
    raw = tmp_path / "raw.tfmap"
    raw.write_bytes(bytes(blob))
    with pytest.raises(ModelFileError, match=f"^{re.escape(str(raw))}: the model file is "
                                             r"truncated or damaged \(Bad CRC-32 for file "
                                             r"'w\.npy'\); save or copy it again$"):
        _read(raw)
    members = _members(saved)
    data = bytearray(members["w.npy"])
    data[-1] ^= 0x01
    bad = _zip(tmp_path / "bad.tfmap", {**members, "w.npy": bytes(data)})
    with pytest.raises(ModelFileError, match=f"^{re.escape(str(bad))}: checksum mismatch: the "
                                             r"file is not the one saved \(SHA-256 [0-9a-f]{64}, "
                                             r"recorded '[0-9a-f]{64}'\); the file is damaged$"):
        _read(bad)
    note = _edit_record(saved, tmp_path / "note.tfmap",
                        lambda r: r.__setitem__("sample_rate", 44100), reseal=False)
    with pytest.raises(ModelFileError, match=f"^{re.escape(str(note))}: checksum mismatch"):
        _read(note)
    same = _zip(tmp_path / "same.tfmap", _members(saved))  # rewritten unchanged: still fine
    assert _read(same).metadata == META


@pytest.mark.parametrize("edit, message", [
    (lambda r: r.__setitem__("version", 3),
     r" was saved by a newer version of talkingface \(test_model version 3; this version reads "
     r"1, 2\); update talkingface$"),
    (lambda r: r.__setitem__("version", 0),
     r": not a test model \(its version is 0, not a positive integer\)$"),
    (lambda r: r.__setitem__("version", "2"),
     r": not a test model \(its version is '2', not a positive integer\)$"),
    (lambda r: r.__setitem__("kind", "motion_units"),
     r": not a test model \(its kind is 'motion_units', expected 'test_model'\)$"),
    (lambda r: r.pop("kind"), r": not a test model \(its kind is None, expected 'test_model'\)$"),
    (lambda r: r.pop("arrays"), r": the metadata has no array manifest$"),
    (lambda r: r["arrays"].pop("w"),
     r": the arrays do not match the metadata \(missing: none; not in the metadata: \['w'\]\)$"),
    (lambda r: r["arrays"].__setitem__("w", {"dtype": "<f4", "shape": [4, 3]}),
     r": array 'w' is <f8 \(4, 3\), the metadata says \{'dtype': '<f4', 'shape': \[4, 3\]\}$"),
], ids=["newer", "zero", "text-version", "kind", "no-kind", "no-manifest", "manifest",
        "dtype"])
def test_bad_records_are_refused_in_one_line(saved, tmp_path, edit, message):
    bad = _edit_record(saved, tmp_path / "bad.tfmap", edit, reseal=True)
    with pytest.raises(ModelFileError, match="^" + re.escape(str(bad)) + message) as e:
        _read(bad)
    _one_line(e)


def test_a_version_this_code_does_not_read_and_an_unresealed_newer_one(saved, tmp_path):
    with pytest.raises(ModelFileError, match=f"^{re.escape(str(saved))}: test_model version 2 is "
                                             r"not read by this version of talkingface \(it "
                                             r"reads 3\)$"):
        _read(saved, versions=(3,))
    # a newer file is refused as newer before its checksum is looked at (it may differ)
    newer = _edit_record(saved, tmp_path / "newer.tfmap",
                         lambda r: r.__setitem__("version", 7), reseal=False)
    with pytest.raises(ModelFileError, match="was saved by a newer version of talkingface"):
        _read(newer)


@pytest.mark.parametrize("where", ["extra", "array", "metadata"])
def test_pickled_object_arrays_are_refused_unread(saved, tmp_path, where):
    marker = tmp_path / "ran"
    payload = np.empty(1, dtype=object)
    payload[0] = Touch(marker)
    members = _members(saved)
    members[{"extra": "evil.npy", "array": "w.npy", "metadata": "metadata.npy"}[where]] = _npy(
        payload, allow_pickle=True)
    bad = _zip(tmp_path / "bad.tfmap", members)
    name = {"extra": "evil", "array": "w", "metadata": "metadata"}[where]
    with pytest.raises(ModelFileError, match=f"^{re.escape(str(bad))}: array '{name}' holds "
                                             r"pickled Python objects; a model file may hold "
                                             r"numbers only, so it is not loaded \(loading it "
                                             r"could run code\)$") as e:
        _read(bad)
    _one_line(e)
    assert not marker.exists()
    pickle.loads(pickle.dumps(Touch(marker)))  # the control: the payload does run if unpickled
    assert marker.exists()


def test_other_archives_and_members_are_refused(saved, tmp_path):
    def refused(path, message):
        with pytest.raises(ModelFileError, match=f"^{re.escape(str(path))}: {message}$") as e:
            _read(path)
        _one_line(e)

    members = _members(saved)
    refused(_zip(tmp_path / "script.tfmap", {"script.py": "print('hi')\n"}),
            r"member 'script\.py' is not one of the model's arrays")
    refused(_zip(tmp_path / "notnpy.tfmap", {**members, "w.npy": b"not an array"}),
            r"member 'w' is not a numpy array \(.*\)")
    refused(_zip(tmp_path / "strings.tfmap", {**members, "s.npy": _npy(np.array(["ab", "c"]))}),
            r"array 's' has dtype <U2 \(2,\); allowed: numbers")
    refused(_zip(tmp_path / "list.tfmap", {**members, "metadata.npy": _npy(np.array(["{}"]))}),
            r"array 'metadata' has dtype <U2 \(1,\); allowed: one string")
    refused(_zip(tmp_path / "norecord.tfmap", {"x.npy": _npy(np.zeros(2))}),
            r"not a test model \(no metadata; its arrays are \['x'\]\)")
    refused(_zip(tmp_path / "text.tfmap", {**members, "metadata.npy": _npy(np.array("hi"))}),
            r"not a test model \(its metadata is not JSON: .*\)")
    refused(_zip(tmp_path / "list2.tfmap", {**members, "metadata.npy": _npy(np.array("[1]"))}),
            r"not a test model \(its metadata is not a JSON object\)")
    compressed = tmp_path / "compressed.tfmap"
    with open(compressed, "wb") as f:
        np.savez_compressed(f, **dict(np.load(saved)))
    refused(compressed, r"member '.*\.npy' is compressed; model files are written uncompressed")
    buf = io.BytesIO()  # a .npy header claiming 8 TB: refused before anything is allocated
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f8", "fortran_order": False,
                                               "shape": (10**12,)})
    refused(_zip(tmp_path / "huge.tfmap", {**members, "x.npy": buf.getvalue() + bytes(8)}),
            r"array 'x' should hold 8000000000000 bytes, the file has 8; the file is damaged")


# -- files written before the model file ---------------------------------------------------------

def test_a_legacy_record_is_returned_as_found_when_asked_for(tmp_path):
    """A file of the older layout (the record under ``header`` or ``metadata``, no kind): its
    arrays parsed as safely, the record returned for the caller to check."""
    arrays = _arrays()
    for member in ("header", "metadata"):
        old = tmp_path / f"old_{member}.npz"
        with open(old, "wb") as f:
            np.savez(f, **{member: np.array(json.dumps({"format": "x/3", **META})), **arrays})
        found = _read(old, legacy=(member,))
        assert (found.kind, found.version, found.member, found.legacy) == (None, None, member,
                                                                           True)
        assert found.metadata == {"format": "x/3", **META}
        assert all(found.arrays[n].tobytes() == a.tobytes() for n, a in arrays.items())
        with pytest.raises(ModelFileError, match={  # not asked for: refused
                "header": r"array 'header' has dtype <U\d+ \(\); allowed: numbers$",
                "metadata": r"not a test model \(its kind is None, expected 'test_model'\)$"}[
                    member]):
            _read(old)
    both = tmp_path / "both.npz"
    with open(both, "wb") as f:
        np.savez(f, header=np.array("{}"), metadata=np.array("{}"))
    with pytest.raises(ModelFileError, match=r"both\.npz: members \['metadata', 'header'\] each "
                                             r"claim to be its record$"):
        _read(both, legacy=("header",))


def test_check_arrays_checks_a_legacy_manifest_and_checksum(tmp_path):
    arrays = {"a": np.arange(3.0), "b": np.ones((2, 2), dtype=np.int32)}
    man, digest = modelfile.manifest(arrays), modelfile.checksum(arrays)
    modelfile.check_arrays(tmp_path / "f", arrays, man, digest, member="header")
    with pytest.raises(ModelFileError, match=r"f: the arrays do not match the header \(missing: "
                                             r"\['c'\]; not in the header: none\)$"):
        modelfile.check_arrays(tmp_path / "f", arrays, {**man, "c": {}}, digest, member="header")
    with pytest.raises(ModelFileError, match=r"f: checksum mismatch"):
        modelfile.check_arrays(tmp_path / "f", {**arrays, "a": np.arange(3.0) + 1}, man, digest)
