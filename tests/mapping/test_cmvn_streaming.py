"""A mapping trained with causal CMVN (issue 12): the streaming animator's frames equal the
offline frames bit for bit — the normalised features and the MUPs — for any chunk size; the
model file keeps the CMVN settings and prior, and a model saved without them loads as "none"."""
import dataclasses
import json

import numpy as np
import pytest

from groundwork import modelfile
from mapping.animator import FaceAnimator, StreamingAnimator
from mapping.checkpoint import AudioMapping
from tests.mapping.small_mapping import stream_frames, train_small


@pytest.fixture(scope="module")
def trained(small_corpus):
    t = train_small(small_corpus, cmvn="meanvar", cmvn_warmup_frames=20)
    return t.mapping, t.units, t.data, t.result


def test_the_experiment_trains_with_the_configured_cmvn(trained):
    mapping, _, data, r = trained
    assert mapping.cmvn == "meanvar" and r.mapper.context_.cmvn_.warmup_frames == 20
    # the experiment's predictions are the model's predictions of the same audio
    u = data[0]
    np.testing.assert_array_equal(r.mapper.predict(u.features, u.expression),
                                  mapping.mapper.predict(mapping.features(u.audio, u.sample_rate),
                                                         u.expression))


@pytest.mark.parametrize("chunk", [1, 333, 735, 4096, 10**7])
def test_streaming_equals_offline_exactly_with_cmvn(trained, small_corpus, chunk):
    mapping, units, _, _ = trained
    animator = FaceAnimator(mapping, units)
    u = small_corpus.utterances[4]  # a smiling utterance
    for expression in ("neutral", "smile") if chunk != 1 else ("smile",):
        offline_feats = mapping.normalized_features(u.audio, u.sample_rate)
        offline = mapping.predict_audio(u.audio, u.sample_rate, expression)
        frames = stream_frames(animator, u.audio, chunk, expression)
        assert [f.index for f in frames] == list(range(len(offline)))
        assert np.array_equal(np.stack([f.features for f in frames]), offline_feats)
        assert np.array_equal(np.stack([f.mups for f in frames]), offline)


def test_a_stream_restarts_its_cmvn_on_reset(trained, small_corpus):
    mapping, units, _, _ = trained
    s = StreamingAnimator(FaceAnimator(mapping, units))
    a, b = small_corpus.utterances[0].audio, small_corpus.utterances[1].audio
    s.push(a)
    s.flush()
    s.reset()
    frames = s.push(b) + s.flush()
    assert np.array_equal(np.stack([f.mups for f in frames]), mapping.predict_audio(b, s.sr))


def test_the_model_file_keeps_cmvn_and_an_old_file_loads_without_it(trained, small_corpus,
                                                                     tmp_path):
    mapping, _, _, _ = trained
    u = small_corpus.utterances[2]
    path = mapping.save(tmp_path / "m.tfmap")
    loaded = AudioMapping.load(path)
    assert loaded.cmvn == "meanvar"
    np.testing.assert_array_equal(loaded.mapper.context_.cmvn_.prior_var_,
                                  mapping.mapper.context_.cmvn_.prior_var_)
    np.testing.assert_array_equal(loaded.predict_audio(u.audio, u.sample_rate),
                                  mapping.predict_audio(u.audio, u.sample_rate))
    header = json.loads(str(np.load(path)["metadata"]))
    assert header["method_params"]["context"]["cmvn"] == "meanvar"
    assert header["method_params"]["cmvn_warmup_frames"] == 20
    assert "mapper/context/cmvn/mean" in header["arrays"]


def test_a_model_saved_before_cmvn_loads_as_none(small_corpus, tmp_path):
    """Strip the CMVN keys from a model without CMVN, as an older version (format /3: the
    record under ``header``, the arrays' SHA-256) wrote it."""
    m = train_small(small_corpus, method="linear", epochs=600).mapping
    path = m.save(tmp_path / "old.tfmap")

    with np.load(path, allow_pickle=False) as z:
        members = {name: z[name] for name in z.files}
    header = json.loads(str(members.pop("metadata")))
    for d in (header["method_params"], header["method_params"]["context"]):
        del d["cmvn"], d["cmvn_warmup_frames"]
    del header["kind"], header["version"]
    header.update(format="talkingface.mapping/3", sha256=modelfile.checksum(members))
    with open(path, "wb") as f:
        np.savez(f, header=np.array(json.dumps(header)), **members)
    old = AudioMapping.load(path)
    assert old.cmvn == "none"
    u = small_corpus.utterances[0]
    np.testing.assert_array_equal(old.predict_audio(u.audio, u.sample_rate),
                                  m.predict_audio(u.audio, u.sample_rate))
