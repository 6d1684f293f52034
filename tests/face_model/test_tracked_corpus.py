"""The tracked copy of a corpus: a valid corpus with the same audio and phones, markers close
to the rendered ones, reproducible from the seed, and never written over an existing folder."""
import csv
import json

import numpy as np
import pytest

from face_model.alignment import speaker_neutrals
from face_model.corpus import Corpus, corpus_hash, load_corpus
from face_model.motion_units import fit_corpus_units
from face_model.tracked_corpus import track_corpus, track_utterance
from groundwork.errors import ParameterError


@pytest.fixture(scope="module")
def units(small_corpus):
    return fit_corpus_units(small_corpus)[0]


@pytest.fixture(scope="module")
def subset(small_corpus):
    """One sentence per expression, with the corpus root (its files are copied)."""
    utts = [small_corpus[f"s00_{e}_001"] for e in ("neutral", "smile", "sad")]
    return Corpus(root=small_corpus.root, info=small_corpus.info, utterances=utts)


@pytest.fixture(scope="module")
def tracked(subset, units, tmp_path_factory):
    out = tmp_path_factory.mktemp("tracked") / "tracked"
    summary = track_corpus(subset, units, out, noise_sd=10.0, seed=3, workers=2,
                           progress=False)
    return out, summary


def test_the_tracked_corpus_is_a_corpus_close_to_the_original(subset, tracked):
    out, summary = tracked
    again = load_corpus(out)  # validates every file
    assert [u.utt_id for u in again.utterances] == [u.utt_id for u in subset.utterances]
    for orig, tr in zip(subset.utterances, again.utterances):
        assert (out / "audio" / f"{tr.utt_id}.wav").read_bytes() == \
            (subset.root / "audio" / f"{orig.utt_id}.wav").read_bytes()
        assert tr.phones == orig.phones and tr.expression == orig.expression
        assert tr.markers.shape == orig.markers.shape
        err = np.linalg.norm(tr.markers - orig.markers, axis=-1)
        assert err.mean() < 0.5 and np.percentile(err, 99) < 2.0, (err.mean(), err.max())
        assert not np.array_equal(tr.markers, orig.markers)  # tracked, not copied
    info = json.loads((out / "corpus.json").read_text())
    assert info["source"] == "tracked" and info["tracker"]["init"] == "image"
    assert info["source_corpus_hash"] == corpus_hash(subset.root)
    with open(out / "tracking.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["utt_id"] for r in rows] == [u.utt_id for u in subset.utterances]
    frames = sum(u.n_frames for u in subset.utterances)
    assert summary["frames"] == frames
    mean = sum(float(r["error_px_mean"]) * int(r["frames"]) for r in rows) / frames
    assert abs(mean - summary["error_px_mean"]) < 1e-3


def test_tracking_is_reproducible_and_the_seed_matters(subset, units, tracked):
    out, _ = tracked
    u = subset.utterances[1]
    neutral = speaker_neutrals(subset)[u.speaker]
    seeds = np.random.SeedSequence(3).generate_state(len(subset.utterances))
    one = track_utterance(u, units, neutral, noise_sd=10.0, seed=int(seeds[1]))
    np.testing.assert_array_equal(one.markers, np.load(out / "markers" / f"{u.utt_id}.npy"))
    other = track_utterance(u, units, neutral, noise_sd=10.0, seed=int(seeds[1]) + 1)
    assert not np.array_equal(one.markers, other.markers)


def test_an_existing_folder_is_not_overwritten(subset, units, tracked):
    out, _ = tracked
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    with pytest.raises(ParameterError, match=r"tracked exists; pass overwrite=True"):
        track_corpus(subset, units, out, progress=False)
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before
    with pytest.raises(ParameterError, match=r"init 'eyes'; allowed: markers, corners, image"):
        track_corpus(subset, units, out.parent / "x", init="eyes", progress=False)


def test_overwrite_swaps_the_new_folder_in_whole(subset, units, tmp_path):
    one = Corpus(root=subset.root, info=subset.info, utterances=subset.utterances[:1])
    out = tmp_path / "tracked"
    out.mkdir()
    (out / "stale.txt").write_text("from before")
    track_corpus(one, units, out, seed=3, workers=1, progress=False, overwrite=True)
    assert not (out / "stale.txt").exists()
    assert [u.utt_id for u in load_corpus(out).utterances] == [one.utterances[0].utt_id]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tracked"]  # no partial, no replaced
