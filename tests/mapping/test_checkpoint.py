"""The saved mapping (``.tfmap``) is data, never code: every method comes back bit for bit, and
a file that is damaged, truncated, of another version or carries a pickle is refused with a
ParameterError naming it, without running anything in it. Files of format /3 (the record under
``header``, before :mod:`groundwork.modelfile`) still load, to the same bits."""
from __future__ import annotations

import io
import json
import pathlib
import pickle
import re
import zipfile

import numpy as np
import pytest

from groundwork import modelfile
from groundwork.errors import ParameterError
from mapping import BASELINES, Baseline, GatedMLP
from mapping.checkpoint import KIND, VERSION, AudioMapping
from mapping.config import TrainSettings
from mapping.dataset import split_masks
from mapping.nets import NetRegressor
from tests.mapping.phone_runs import A0, phone_run_data

EXPRESSIONS = ("neutral", "smile", "sad")
# Round trips need trained models, not good ones: a few epochs.
TRAIN = TrainSettings(max_epochs=12, patience=4)


def synthetic_data(seed: int = 0, n_utt: int = 3) -> list:
    return phone_run_data(seed, n_utt=n_utt, n_seg=10, seg_len=6, expressions=EXPRESSIONS)


@pytest.fixture(scope="module")
def data():
    return synthetic_data()


@pytest.fixture(scope="module")
def masks(data):
    return split_masks(data, "random_frames", train_fraction=0.8, seed=0)


def wrap(mapper) -> AudioMapping:
    return AudioMapping(mapper, sample_rate=22050, n_utterance=A0, rest_mups=np.zeros(A0),
                        metadata={"note": "checkpoint test"})


def assert_same_predictions(a, b, data, expressions) -> None:
    """Bit-identical MUPs of every utterance under every expression (and frame by frame, for
    the methods the streaming animator can use)."""
    for d in data:
        for e in expressions:
            pa, pb = a.predict(d.features, e), b.predict(d.features, e)
            assert pa.dtype == pb.dtype == np.float32 and pa.shape == pb.shape
            assert pa.tobytes() == pb.tobytes(), (d.utt_id, e)
    if getattr(a, "sequence", False):
        return
    X = a.context_.transform(data[-1].features)
    for e in expressions:
        assert a.predict_stacked(X[3:4], e).tobytes() == b.predict_stacked(X[3:4], e).tobytes()


def read_members(path) -> dict:
    with np.load(path, allow_pickle=False) as z:
        return {name: z[name] for name in z.files}


def write_members(path, members: dict, *, changes: dict | None = None,
                  refresh: bool = True, allow_pickle: bool = False) -> pathlib.Path:
    """An npz of ``members`` (``metadata`` a JSON string) with ``changes`` to the record; with
    ``refresh``, the record's array manifest and checksum describe the arrays and the record
    written (a file consistent in itself)."""
    record = json.loads(str(members["metadata"]))
    record.update(changes or {})
    arrays = {n: a for n, a in members.items() if n != "metadata"}
    if refresh:
        numeric = {n: a for n, a in arrays.items() if a.dtype != object}
        record["arrays"] = modelfile.manifest(numeric)
        record.pop("sha256", None)
        record["sha256"] = modelfile.checksum(numeric, record)
    with open(path, "wb") as f:
        np.savez(f, allow_pickle=allow_pickle, metadata=np.array(json.dumps(record)), **arrays)
    return pathlib.Path(path)


def write_format_3(path, members: dict, *, changes: dict | None = None) -> pathlib.Path:
    """The model of ``members`` (a version-4 file's) as format /3 wrote it, with ``changes`` to
    its header: the record under ``header`` with ``format``, the array manifest and the SHA-256
    of the arrays alone (no kind, no version)."""
    record = json.loads(str(members["metadata"]))
    arrays = {n: a for n, a in members.items() if n != "metadata"}
    for key in ("kind", "version", "sha256"):
        del record[key]
    header = {**record, "format": "talkingface.mapping/3", "arrays": modelfile.manifest(arrays),
              "sha256": modelfile.checksum(arrays), **(changes or {})}
    with open(path, "wb") as f:
        np.savez(f, allow_pickle=False, header=np.array(json.dumps(header, sort_keys=True)),
                 **arrays)
    return pathlib.Path(path)


class Touch:
    """Unpickling this creates the file ``marker`` (a stand-in for arbitrary code)."""

    def __init__(self, marker):
        self.marker = pathlib.Path(marker)

    def __reduce__(self):
        return pathlib.Path.touch, (self.marker,)


@pytest.fixture(scope="module")
def gated(data, masks):
    return GatedMLP(n_utterance=A0, min_class_frames=15, gate_components=2, train=TRAIN,
                    random_state=3).fit(data, masks)


@pytest.fixture
def saved(gated, tmp_path):
    return wrap(gated).save(tmp_path / "m.tfmap")


# -- round trips --------------------------------------------------------------------------------

GATED_CASES = [("cascade", 44, "diag"), ("bank", 44, "diag"), ("cascade", 8, "diag"),
               ("bank", 8, "diag"), ("cascade", 44, "full"), ("bank", 8, "tied"),
               ("cascade", 8, "spherical")]


@pytest.mark.parametrize("expression_model, n_classes, covariance", GATED_CASES,
                         ids=["-".join(map(str, c)) for c in GATED_CASES])
def test_gated_mlp_round_trip(data, masks, tmp_path, expression_model, n_classes, covariance):
    m = GatedMLP(n_utterance=A0, n_classes=n_classes, gate_components=2,
                 gate_covariance=covariance, min_class_frames=15, expression_model=expression_model,
                 hidden_min=4, hidden_max=9, cascade_hidden=6, train=TRAIN, random_state=1)
    m.fit(data, masks)
    path = wrap(m).save(tmp_path / "runs" / "x" / "mapping" / "gated_mlp_utterance.tfmap")
    assert sorted(p.name for p in path.parent.iterdir()) == [path.name]  # no temporary left
    loaded = AudioMapping.load(path)
    g = loaded.mapper
    assert isinstance(g, GatedMLP)
    assert loaded.expressions == ("neutral", "sad", "smile") == wrap(m).expressions
    assert loaded.metadata == {"note": "checkpoint test"}
    assert_same_predictions(m, g, data, loaded.expressions)
    for d in data[::3]:
        np.testing.assert_array_equal(g.gate_classes(d.features), m.gate_classes(d.features))
    # the fitted state the gate report and the animator read, and every hyper-parameter
    assert g.merges_ == m.merges_ and g.class_names_ == m.class_names_
    assert g.expressions_ == m.expressions_ and g.n_mups_ == m.n_mups_
    np.testing.assert_array_equal(g.group_of_phone_, m.group_of_phone_)
    assert sorted(g.bank_.nets_) == sorted(m.bank_.nets_) and g.bank_.hidden_ == m.bank_.hidden_
    for name in ("n_utterance", "context_back", "context_forward", "n_classes", "gate_components",
                 "gate_covariance", "min_class_frames", "hidden_min", "hidden_max",
                 "expression_model", "cascade_hidden", "train", "random_state"):
        assert getattr(g, name) == getattr(m, name), name
    expert = g.experts_["smile"]
    assert isinstance(expert, NetRegressor if expression_model == "cascade" else type(g.bank_))
    # the file holds numbers and one JSON string, nothing else
    with zipfile.ZipFile(path) as z, np.load(path, allow_pickle=False) as npz:
        assert all(i.filename.endswith(".npy") for i in z.infolist())
        kinds = {npz[n].dtype.kind for n in npz.files if n != "metadata"}
        assert kinds <= set("biuf") and npz["metadata"].dtype.kind == "U"
    # saving the loaded model writes the same model again
    again = read_members(wrap(g).save(tmp_path / "again.tfmap"))
    first = read_members(path)
    assert str(again["metadata"]) == str(first["metadata"])
    # the estimators' own pair, on plain dicts
    arrays, params = m.to_arrays()
    assert_same_predictions(m, GatedMLP.from_arrays(arrays, json.loads(json.dumps(params))),
                            data, loaded.expressions)


@pytest.mark.parametrize("kind", BASELINES)
def test_baseline_round_trip(data, masks, tmp_path, kind):
    b = Baseline(kind, train=TRAIN, random_state=2).fit(data, masks)
    path = wrap(b).save(tmp_path / f"{kind}.tfmap")
    loaded = AudioMapping.load(path)
    assert isinstance(loaded.mapper, Baseline) and loaded.mapper.kind == kind
    assert loaded.expressions == ("neutral", "sad", "smile")
    assert list(loaded.mapper.models_) == list(b.models_)
    assert loaded.mapper.context_.n_inputs == b.context_.n_inputs
    assert loaded.mapper.train == b.train and loaded.mapper.random_state == 2
    assert_same_predictions(b, loaded.mapper, data, b.models_)
    record = json.loads(str(read_members(path)["metadata"]))
    assert (record["kind"], record["version"]) == (KIND, VERSION) == ("audio_mapping", 4)
    assert record["method"] == kind and "format" not in record


# -- nothing in a file is executed ---------------------------------------------------------------

def test_the_payload_would_run_if_unpickled(tmp_path):
    """The control: unpickling the payload does create its marker file."""
    marker = tmp_path / "ran"
    pickle.loads(pickle.dumps(Touch(marker)))
    assert marker.exists()


@pytest.mark.parametrize("fmt", ["talkingface.mapping/1", "talkingface.mapping/2"])
def test_old_pickled_models_are_refused_unread(tmp_path, fmt):
    marker = tmp_path / "ran"
    path = tmp_path / "runs" / "demo" / "mapping" / "gated_mlp_utterance.tfmap"
    path.parent.mkdir(parents=True)
    header = {"format": fmt, "sample_rate": 22050, "method": "gated_mlp", "metadata": {}}
    path.write_bytes(json.dumps(header).encode() + b"\n" + pickle.dumps(Touch(marker)))
    message = (re.escape(str(path)) + r" was saved by an older version that stored Python "
               r"objects .*; re-train it with `talkingface train --name demo`")
    with pytest.raises(ParameterError, match=message):
        AudioMapping.load(path)
    assert not marker.exists()
    elsewhere = tmp_path / "model.tfmap"  # outside a run folder: the run name is not known
    elsewhere.write_bytes(path.read_bytes())
    with pytest.raises(ParameterError, match=r"`talkingface train --name NAME`"):
        AudioMapping.load(elsewhere)
    bare = tmp_path / "bare.tfmap"  # a pickle with no header at all
    bare.write_bytes(pickle.dumps(Touch(marker)))
    with pytest.raises(ParameterError, match="not a talkingface mapping model"):
        AudioMapping.load(bare)
    assert not marker.exists()


@pytest.mark.parametrize("where", ["extra", "array", "metadata"])
def test_pickles_smuggled_into_the_npz_are_refused(saved, tmp_path, where):
    """An object array (a pickle) inside the archive: added, in place of an array, or as the
    record. The manifest and checksum are made to agree, so only the pickle is wrong."""
    marker = tmp_path / "ran"
    members = read_members(saved)
    payload = np.empty(1, dtype=object)
    payload[0] = Touch(marker)
    if where == "extra":
        members["mapper/bank/nets/0/extra"] = payload
    elif where == "array":
        members["mapper/context/normalizer/mean"] = payload
    else:
        members["metadata"] = payload
    bad = tmp_path / "bad.tfmap"
    if where == "metadata":
        with open(bad, "wb") as f:
            np.savez(f, allow_pickle=True, **members)
    else:
        write_members(bad, members, allow_pickle=True)
    with pytest.raises(ParameterError, match=re.escape(str(bad)) + r": array '.*' holds pickled "
                                             r"Python objects"):
        AudioMapping.load(bad)
    assert not marker.exists()


# -- damaged files -------------------------------------------------------------------------------

def test_truncated_files_are_refused(saved, tmp_path):
    blob = saved.read_bytes()
    for cut in (0, 1, 3, 4, 30, 200, len(blob) // 3, len(blob) // 2, len(blob) - 100,
                len(blob) - 22, len(blob) - 1):
        cut_path = tmp_path / f"cut{cut}.tfmap"
        cut_path.write_bytes(blob[:cut])
        with pytest.raises(ParameterError, match=re.escape(str(cut_path)) + ": "):
            AudioMapping.load(cut_path)


def test_a_flipped_byte_is_found(saved, gated, tmp_path):
    members = read_members(saved)
    name = "mapper/bank/nets/0/state/net.0.weight"
    # in the archive itself: zip's own CRC of the member catches it
    blob = bytearray(saved.read_bytes())
    at = bytes(blob).find(members[name].tobytes()) + 5
    blob[at] ^= 0x10
    raw = tmp_path / "raw.tfmap"
    raw.write_bytes(bytes(blob))
    with pytest.raises(ParameterError, match=re.escape(str(raw)) + ": the model file is "
                                             "truncated or damaged"):
        AudioMapping.load(raw)
    # in an array of a consistent archive: the record's SHA-256 catches it
    flipped = members[name].copy()
    flipped.view(np.uint8)[5] ^= 0x10
    bad = write_members(tmp_path / "bad.tfmap", {**members, name: flipped}, refresh=False)
    with pytest.raises(ParameterError, match=re.escape(str(bad)) + ": checksum mismatch"):
        AudioMapping.load(bad)
    # the untouched arrays rewritten the same way load fine: the check is not too strict
    same = AudioMapping.load(write_members(tmp_path / "same.tfmap", members, refresh=False))
    d = synthetic_data(seed=5, n_utt=1)[0]
    assert same.mapper.predict(d.features).tobytes() == gated.predict(d.features).tobytes()


def test_arrays_that_disagree_with_the_record_are_refused(saved, tmp_path):
    members = read_members(saved)
    name = "mapper/context/normalizer/scale"
    missing = {n: a for n, a in members.items() if n != name}
    bad = write_members(tmp_path / "missing.tfmap", missing, refresh=False)
    with pytest.raises(ParameterError, match=r"the arrays do not match the metadata \(missing: "
                                             r"\['mapper/context/normalizer/scale'\]"):
        AudioMapping.load(bad)
    # consistent manifest and checksum, but not the shape the model needs
    short = write_members(tmp_path / "short.tfmap", {**members, name: members[name][:2]})
    with pytest.raises(ParameterError, match=re.escape(str(short)) + r": array 'context/"
                                             r"normalizer/scale' must have shape \(4,\), got "
                                             r"\(2,\)"):
        AudioMapping.load(short)
    extra = write_members(tmp_path / "extra.tfmap", {**members, "mapper/spare": np.zeros(3)})
    with pytest.raises(ParameterError, match=r"arrays \['spare'\] belong to no part"):
        AudioMapping.load(extra)
    renamed = {("other/x" if n == name else n): a for n, a in members.items()}
    with pytest.raises(ParameterError, match=r"array 'other/x' is <f8 \(4,\), not one of the "
                                             r"method's \(their names start with 'mapper/'\)"):
        AudioMapping.load(write_members(tmp_path / "renamed.tfmap", renamed))
    # a manifest entry that is not the array's: named with what the record says
    shape = tmp_path / "shape.tfmap"
    record = json.loads(str(members["metadata"]))
    record["arrays"][name]["shape"] = [7, 7, 7]
    del record["sha256"]
    record["sha256"] = modelfile.checksum({n: a for n, a in members.items() if n != "metadata"},
                                          record)
    with open(shape, "wb") as f:
        np.savez(f, **{**members, "metadata": np.array(json.dumps(record))})
    with pytest.raises(ParameterError, match=re.escape(f"{shape}: array '{name}' is <f8 (4,), the "
                                                       "metadata says {'dtype': '<f8', 'shape': "
                                                       "[7, 7, 7]}")):
        AudioMapping.load(shape)


@pytest.mark.parametrize("changes, message", [
    ({"version": 5}, r" was saved by a newer version of talkingface \(audio_mapping version 5; "
                     r"this version reads 4\); update talkingface$"),
    ({"version": 3}, r": audio_mapping version 3 is not read by this version of talkingface "
                     r"\(it reads 4\)$"),
    ({"version": "4"}, r": not a talkingface mapping model \(its version is '4', not a positive "
                       r"integer\)$"),
    ({"kind": "motion_units"}, r": not a talkingface mapping model \(its kind is "
                               r"'motion_units', expected 'audio_mapping'\)$"),
    ({"kind": None}, r": not a talkingface mapping model \(its kind is None"),
    ({"method": "knn"}, r": unknown mapping method 'knn'; allowed: gated_mlp, vq"),
    ({"expressions": ["neutral"]}, r": the metadata lists expressions \['neutral'\]"),
    ({"method_params": {"n_utterance": 3}}, r": malformed talkingface mapping model record "
                                            r"\(KeyError"),
    ({"rest_mups": [0.0]}, r": rest_mups must have shape \(3,\)"),
], ids=["newer", "older", "version-text", "kind", "no-kind", "method", "expressions", "params",
        "rest"])
def test_bad_records_are_refused(saved, tmp_path, changes, message):
    bad = write_members(tmp_path / "bad.tfmap", read_members(saved), changes=changes)
    with pytest.raises(ParameterError, match=re.escape(str(bad)) + message):
        AudioMapping.load(bad)


def test_an_edited_record_is_a_checksum_mismatch(saved, tmp_path):
    """The checksum covers the record too: a hand-edited setting is refused, not used."""
    bad = write_members(tmp_path / "bad.tfmap", read_members(saved),
                        changes={"silence_dbfs": -10.0}, refresh=False)
    with pytest.raises(ParameterError, match=re.escape(str(bad)) + r": checksum mismatch: the "
                                             r"file is not the one saved \(SHA-256 [0-9a-f]{64}, "
                                             r"recorded '[0-9a-f]{64}'\); the file is damaged$"):
        AudioMapping.load(bad)


# -- format /3 ------------------------------------------------------------------------------

@pytest.mark.parametrize("method", ["gated", "linear"])
def test_a_format_3_file_loads_bit_identically(gated, data, masks, tmp_path, method):
    """A model saved by format /3 (the record under ``header``, the arrays' SHA-256 only) loads
    to the same model as the new file, and saving it again writes version 4."""
    mapper = gated if method == "gated" else Baseline("linear", random_state=0).fit(data, masks)
    new = wrap(mapper).save(tmp_path / "new.tfmap")
    old = write_format_3(tmp_path / "old.tfmap", read_members(new))
    with np.load(old, allow_pickle=False) as z:
        assert "metadata" not in z.files and json.loads(str(z["header"]))["format"] == (
            "talkingface.mapping/3")
    a, b = AudioMapping.load(new), AudioMapping.load(old)
    assert b.metadata == a.metadata == {"note": "checkpoint test"}
    assert (b.sample_rate, b.fps, b.n_mfcc, b.deltas, b.window_align, b.silence_dbfs) == (
        a.sample_rate, a.fps, a.n_mfcc, a.deltas, a.window_align, a.silence_dbfs)
    assert b.rest_mups.tobytes() == a.rest_mups.tobytes() and b.expressions == a.expressions
    assert_same_predictions(a.mapper, b.mapper, data, a.expressions)
    assert_same_predictions(mapper, b.mapper, data, a.expressions)
    again = read_members(b.save(tmp_path / "again.tfmap"))
    assert str(again["metadata"]) == str(read_members(new)["metadata"])


@pytest.mark.parametrize("changes, message", [
    ({"format": "talkingface.mapping/2"}, r" was saved by an older version that stored Python "
                                          r"objects \(format 'talkingface\.mapping/2'\)"),
    ({"format": "someone.else/3"}, r": not a talkingface mapping model \(expected format "
                                   r"'talkingface\.mapping/3' in its header, got format "
                                   r"'someone\.else/3'\)$"),
    ({"format": None}, r": not a talkingface mapping model \(expected format "
                       r"'talkingface\.mapping/3' in its header, got format None\)$"),
    ({"sha256": "0" * 64}, r": checksum mismatch: the file is not the one saved"),
    ({"arrays": {}}, r": the arrays do not match the header \(missing: none; not in the "
                     r"header: \['mapper/"),
    ({"method": "knn"}, r": unknown mapping method 'knn'"),
], ids=["older", "foreign", "no-format", "checksum", "manifest", "method"])
def test_bad_format_3_headers_are_refused(saved, tmp_path, changes, message):
    bad = write_format_3(tmp_path / "bad.tfmap", read_members(saved), changes=changes)
    with pytest.raises(ParameterError, match=re.escape(str(bad)) + message):
        AudioMapping.load(bad)


def test_other_archives_are_refused(saved, tmp_path):
    no_header = tmp_path / "no_header.tfmap"
    with open(no_header, "wb") as f:
        np.savez(f, x=np.zeros(3))
    with pytest.raises(ParameterError, match=r"not a talkingface mapping model \(no metadata"):
        AudioMapping.load(no_header)
    for member in ("metadata", "header"):  # the record of version 4, of format /3
        text_header = tmp_path / f"text_{member}.tfmap"
        with open(text_header, "wb") as f:
            np.savez(f, **{member: np.array("hello")})
        with pytest.raises(ParameterError, match=f"its {member} is not JSON"):
            AudioMapping.load(text_header)
    other = tmp_path / "other.tfmap"  # a zip that is not an npz
    with zipfile.ZipFile(other, "w") as z:
        z.writestr("script.py", "print('hello')\n")
    with pytest.raises(ParameterError, match=r"member 'script\.py' is not one of the model's "
                                             r"arrays"):
        AudioMapping.load(other)
    not_npy = tmp_path / "not_npy.tfmap"
    with zipfile.ZipFile(not_npy, "w") as z:
        z.writestr("header.npy", "not an array")
    with pytest.raises(ParameterError, match=r"member 'header' is not a numpy array"):
        AudioMapping.load(not_npy)
    compressed = tmp_path / "compressed.tfmap"  # save writes stored members: no zip bombs
    with open(compressed, "wb") as f:
        np.savez_compressed(f, **read_members(saved))
    with pytest.raises(ParameterError, match=r"member '.*\.npy' is compressed"):
        AudioMapping.load(compressed)
    huge = tmp_path / "huge.tfmap"  # a .npy header claiming 8 TB: refused before allocating
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": "<f8", "fortran_order": False,
                                               "shape": (10**12,)})
    with zipfile.ZipFile(huge, "w") as z:
        z.writestr("mapper/x.npy", buf.getvalue() + bytes(8))
    with pytest.raises(ParameterError, match=r"array 'mapper/x' should hold 8000000000000 bytes, "
                                             r"the file has 8"):
        AudioMapping.load(huge)


def test_a_record_cannot_make_huge_networks(saved, tmp_path):
    """Network sizes come from the record, but the stored arrays must fit them before
    anything is allocated."""
    members = read_members(saved)
    record = json.loads(str(members["metadata"]))
    record["method_params"]["bank"]["nets"][0]["arguments"]["n_hidden"] = 10**7
    bad = write_members(tmp_path / "bad.tfmap", members, changes=record)
    with pytest.raises(ParameterError, match=r"array 'bank/nets/0/state/net\.0\.weight' must have "
                                             r"shape \(10000000, 28\), got \(\d+, 28\)"):
        AudioMapping.load(bad)


def test_a_method_without_arrays_cannot_be_saved(tmp_path):
    class Opaque:
        name = "opaque"

        def predict(self, features, expression="neutral"):
            return features

    with pytest.raises(ParameterError, match="method Opaque cannot be saved: it has no "
                                             r"to_arrays\(\)"):
        wrap(Opaque()).save(tmp_path / "o.tfmap")
    assert not (tmp_path / "o.tfmap").exists()


def test_saving_over_a_model_replaces_it_whole(gated, data, masks, tmp_path):
    path = wrap(gated).save(tmp_path / "m.tfmap")
    linear = Baseline("linear").fit(data, masks)
    wrap(linear).save(path)
    assert AudioMapping.load(path).mapper.kind == "linear"
    assert [p.name for p in tmp_path.iterdir()] == ["m.tfmap"]
    assert io.BytesIO(path.read_bytes()).read(4) == b"PK\x03\x04"
