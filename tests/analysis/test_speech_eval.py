"""The real-speech evaluation set loads and refuses damaged copies by name; the measures recover
known answers on constructed tracks; the shipped labels are what their sources and the aligner
give; the reference recogniser reads a real recording."""
from __future__ import annotations

import hashlib
import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from analysis.speech_eval import (NATIVE, closed_threshold, rate_audio, reference_opening,
                                  training_speakers)
from analysis.speech_scores import (Contact, correlation, fit_frames, frame_accuracy,
                                    phone_frames, segment_contact, viseme_index)
from analysis.speech_recogniser import PhoneRecogniser
from analysis.dev_rule import DEV_RULE, dev_choice
from analysis.speech_set import (SET_DIR, SPEAKER_ID, load_speech_set, phone_class,
                                 read_manifest)
from data_synth.config import SynthConfig
from face_model.corpus import PhoneSegment
from face_model.layout import default_layout
from face_model.phones import BILABIALS, PHONE_INDEX, VISEMES
from groundwork.errors import CorpusError, ParameterError

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))
import align_real_speech  # noqa: E402

FPS = 30


@pytest.fixture(scope="module")
def speech_set():
    return load_speech_set()


@pytest.fixture
def set_copy(tmp_path):
    return Path(shutil.copytree(SET_DIR, tmp_path / "set"))


def test_the_shipped_set_is_16k_mono_with_labels_covering_the_audio(speech_set):
    assert len(speech_set) >= 54  # 14 recordings found in packages, 40 GRID s1 sentences, FSDD
    speakers = {it.speaker for it in speech_set}
    assert {"arctic-slt", "arctic-awb", "librivox-ss01", "praatio-bobby", "grid-s1"} <= speakers
    assert all(SPEAKER_ID.match(s) for s in speakers)
    for it in speech_set:
        assert it.sr == 16000 and it.audio.ndim == 1
        assert it.phones[0].start_s == 0 and abs(it.phones[-1].end_s - it.duration_s) < 0.01
        assert all(a.end_s == b.start_s for a, b in zip(it.phones, it.phones[1:]))
    assert sum(it.duration_s for it in speech_set) > 160
    grid = next(it for it in speech_set if it.speaker == "grid-s1")
    assert getattr(grid, "native_sr", 22050) == 22050  # the FLAC's own rate is kept


def test_every_source_licence_sits_beside_its_files():
    for folder, licence in (("arctic", "COPYING"), ("pocketsphinx", "LICENSE"),
                            ("praatio", "LICENSE")):
        assert (SET_DIR / folder / licence).is_file()
    assert "Any modifications must be clearly marked" in (SET_DIR / "arctic" /
                                                          "COPYING").read_text()
    # every recording's provenance is written down, with its hash: in the README, or for the
    # FSDD part (300 files) in its SHA256SUMS beside its NOTICE (CC BY-SA 4.0)
    written = (SET_DIR / "README.md").read_text() + (SET_DIR / "fsdd" / "SHA256SUMS").read_text()
    assert "CC BY-SA 4.0" in (SET_DIR / "fsdd" / "NOTICE.md").read_text()
    for row in read_manifest():
        digest = hashlib.sha256((SET_DIR / row["wav"]).read_bytes()).hexdigest()
        assert digest in written, row["id"]


@pytest.mark.parametrize("damage, message", [
    (lambda d: (d / "manifest.csv").unlink(), r"manifest\.csv: manifest not found"),
    (lambda d: (d / "manifest.csv").write_text("id,wav\nx,y.wav\n"),
     r"manifest\.csv: missing columns \['labels'"),
    (lambda d: (d / "praatio" / "bobby.wav").unlink(), r"praatio/bobby\.wav: audio file of "
     r"'praatio_bobby' not found"),
    (lambda d: (d / "praatio" / "bobby.csv").write_text("start_s,end_s,phone\n0,1.1946,zz\n"),
     r"praatio/bobby\.csv, line 2: unknown phone 'zz'"),
    (lambda d: (d / "praatio" / "bobby.csv").write_text("start_s,end_s,phone\n0,0.5,sil\n"
                                                        "0.6,1.1946,b\n"),
     r"praatio/bobby\.csv, line 3: segment 0\.6–1\.1946 s must start where the previous one "
     r"ends \(0\.5 s\)"),
    (lambda d: (d / "praatio" / "bobby.csv").write_text("start_s,end_s,phone\n0,0.9,sil\n"),
     r"praatio/bobby\.csv: the last phone ends at 0\.9000 s but the audio lasts 1\.1946 s"),
    (lambda d: (d / "manifest.csv").write_text(
        (d / "manifest.csv").read_text().replace(",hts,", ",guess,")),
     r"manifest\.csv, line 2: label_source 'guess'"),
    (lambda d: (d / "manifest.csv").write_text(
        (d / "manifest.csv").read_text().replace(",test,", ",train,", 1)),
     r"manifest\.csv, line 2: part 'train'; allowed: dev, test \(or empty: test\)"),
])
def test_a_damaged_set_is_refused_naming_the_file(set_copy, damage, message):
    damage(set_copy)
    with pytest.raises(CorpusError, match=message):
        load_speech_set(set_copy)


def test_phone_symbols_map_to_the_44_classes():
    assert [phone_class(s) for s in ("AA1", "pau", "ax", "IY0", "axr", "", "HH")] == [
        "aa", "sil", "ax", "iy", "er", "sil", "hh"]
    with pytest.raises(CorpusError, match="'qq' in x.lab has no class"):
        phone_class("qq", source="x.lab")


def test_the_shipped_labels_are_what_their_sources_and_the_aligner_give(tmp_path):
    # HTS (slt), the TextGrid (bobby) and pocketsphinx 5.1.1 forced alignment (goforward)
    log = tmp_path / "log.txt"
    with open(log, "w") as out:
        differ = align_real_speech.regenerate(ids={"slt_a0009", "praatio_bobby",
                                                   "ps_goforward"}, check=True, out=out)
    assert differ == [], log.read_text()
    assert log.read_text().count("same") == 3


def _segs(spec):
    """[(phone, duration_s), ...] → contiguous PhoneSegments from 0."""
    out, t = [], 0.0
    for p, d in spec:
        out.append(PhoneSegment(t, t + d, p))
        t += d
    return out


def test_closure_fraction_is_exactly_k_of_n_on_a_constructed_track():
    # five /p b m/ segments of 0.1 s between vowels; the lips meet in segments 0, 2 and 3 only
    segs = _segs([("aa", 0.2)] + sum([[(p, 0.1), ("aa", 0.2)] for p in "pbmpm"], []))
    n = int(round(segs[-1].end_s * FPS))
    opening = np.full(n, 8.0)
    closed = [0, 2, 3]
    for i, s in enumerate(s for s in segs if s.phone in BILABIALS):
        if i in closed:
            k = int(round(0.5 * (s.start_s + s.end_s) * FPS))
            opening[k] = -0.3
    c = segment_contact(opening, FPS, segs, BILABIALS, threshold=2.1)
    assert c.n == 5 and c.met.tolist() == [True, False, True, True, False]
    assert c.fraction == 3 / 5
    # a segment shorter than a frame still gets the frame nearest its centre
    short = _segs([("aa", 0.3), ("m", 0.01), ("aa", 0.3)])
    op = np.full(19, 8.0)
    op[9] = 0.0
    assert segment_contact(op, FPS, short, BILABIALS, 2.1).met.tolist() == [True]
    assert np.isnan(Contact(np.zeros(0, bool), np.zeros(0)).fraction)


def test_correlation_and_frame_accuracy_recover_known_values(rng):
    x = rng.standard_normal(200)
    assert correlation(x, x) == pytest.approx(1.0)
    assert correlation(x, -3 * x + 2) == pytest.approx(-1.0)
    assert np.isnan(correlation(x, np.ones(200)))
    assert frame_accuracy([1, 2, 3, 4], [1, 2, 0, 0]) == 0.5
    segs = _segs([("sil", 0.1), ("m", 0.1), ("iy", 0.2)])
    frames = phone_frames(segs, np.arange(12) / FPS)
    assert [int(f) for f in frames[[0, 3, 6, 11]]] == [PHONE_INDEX[p] for p in
                                                       ("sil", "m", "iy", "iy")]
    assert [VISEMES[v] for v in viseme_index(frames[[0, 3, 6]])] == ["neutral", "m", "i"]


def test_the_generators_own_reference_closes_every_bilabial_and_touches_every_f_v(speech_set):
    """The threshold comes from the generator's closed mouths: its own rendering of the real
    labels passes both tests on every segment, and its vowels stay well above it."""
    synth = SynthConfig()
    threshold = closed_threshold(default_layout().neutral)
    assert 2.0 < threshold < 2.2
    for it in speech_set[:4]:
        n = int(np.ceil(it.duration_s * FPS))
        ref = reference_opening(it.phones, n, FPS, synth, 2002)
        assert segment_contact(ref, FPS, it.phones, BILABIALS, threshold).fraction == 1.0
        lab = segment_contact(ref, FPS, it.phones, {"f", "v"}, threshold)
        assert lab.n == 0 or lab.fraction == 1.0


def test_the_recogniser_reads_a_real_recording(speech_set):
    it = next(i for i in speech_set if i.id == "ps_goforward")
    rec = PhoneRecogniser()
    whole = rec.whole(it.audio, it.sr)
    stream = rec.streaming(it.audio, it.sr, 0.1)
    true = phone_frames(it.phones, np.arange(len(whole)) / FPS)
    assert len(whole) == len(stream) == int(np.ceil(it.duration_s * FPS))
    assert frame_accuracy(viseme_index(true), viseme_index(whole)) > 0.8
    assert frame_accuracy(viseme_index(true), viseme_index(stream)) > 0.7


def test_training_speakers_of_a_synthetic_corpus_are_its_voices_real_speakers(tmp_path):
    corpus = tmp_path / "corpus"
    corpus.mkdir()
    (corpus / "corpus.json").write_text(json.dumps({"settings": {"backend": "espeak"}}))
    (corpus / "manifest.csv").write_text("utt_id,speaker,voice\na,s00,flite:slt\n"
                                         "b,s00,espeak:en-us+m3\nc,s01,flite:awb\n")
    # the synthetic face's speaker (s00) is no real speaker; the voices are
    assert training_speakers(corpus) == {"arctic-slt", "arctic-awb", "espeak"}
    # no voice column: the corpus's one backend voice
    (corpus / "manifest.csv").write_text("utt_id,speaker\na,s00\n")
    assert training_speakers(corpus) == {"espeak"}
    (corpus / "corpus.json").write_text(json.dumps({"settings": {"backend": "flite"}}))
    assert training_speakers(corpus) == {"arctic-slt"}
    (corpus / "manifest.csv").unlink()
    with pytest.raises(CorpusError, match=r"manifest\.csv: manifest not found \(the training "
                       r"corpus's manifest is needed to tell seen from unseen speakers\)"):
        training_speakers(corpus)


def test_training_speakers_of_a_given_corpus_are_its_manifests_speakers(tmp_path):
    corpus = tmp_path / "grid"
    corpus.mkdir()
    (corpus / "corpus.json").write_text(json.dumps({"source": "GRID s1 video",
                                                    "settings": {"speaker": "grid-s1"}}))
    (corpus / "manifest.csv").write_text("utt_id,speaker\na,grid-s1\nb,Grid-S1\n")
    assert training_speakers(corpus) == {"grid-s1"}
    # a given corpus that also lists synthetic voices: both kinds
    (corpus / "manifest.csv").write_text("utt_id,speaker,voice\na,grid-s1,\nb,grid-s1,"
                                         "flite:rms\n")
    assert training_speakers(corpus) == {"grid-s1", "arctic-rms"}
    # a folder of recordings with no corpus.json is given too
    (corpus / "corpus.json").unlink()
    assert training_speakers(corpus) == {"grid-s1", "arctic-rms"}


def test_the_shipped_grid_corpus_is_seen_by_a_model_trained_on_it(speech_set):
    import face_model
    builtin = Path(face_model.__file__).parent / "real_faces" / "grid-s1"
    seen = training_speakers(builtin)
    assert seen == {"grid-s1"}
    assert {it.speaker for it in speech_set if it.speaker in seen} == {"grid-s1"}


def test_a_prediction_off_by_more_than_rounding_is_an_error():
    assert len(fit_frames(np.arange(10), 11, what="x")) == 11  # one frame: rounding, padded
    assert fit_frames(np.arange(10), 9, what="x").tolist() == list(range(9))
    with pytest.raises(ParameterError, match=r"slt at native: 10 frames predicted for labels "
                       r"of 12 frames; allowed: within 1"):
        fit_frames(np.arange(10), 12, what="slt at native")


def test_rate_variants_resample_down_and_mark_what_is_already_low(speech_set):
    slt = next(it for it in speech_set if it.id == "slt_a0009")  # a 16 kHz file
    y, sr, note = rate_audio(slt, NATIVE)
    assert sr == 16000 and note == "" and np.array_equal(y, slt.audio)
    y16, sr16, note16 = rate_audio(slt, 16000)
    assert sr16 == 16000 and "scored once" in note16 and np.array_equal(y16, slt.audio)
    y8, sr8, note8 = rate_audio(slt, 8000)
    assert sr8 == 8000 and note8 == "" and abs(len(y8) - len(slt.audio) / 2) <= 1
    grid = next(it for it in speech_set if it.speaker == "grid-s1")
    assert rate_audio(grid, NATIVE)[1] == getattr(grid, "native_sr", grid.sr)
    assert rate_audio(grid, 16000)[1] == 16000


def test_the_set_is_split_by_speaker_into_development_and_test_parts(speech_set):
    parts = {}
    for it in speech_set:
        parts.setdefault(it.speaker, set()).add(it.part)
    assert all(len(p) == 1 for p in parts.values())  # no speaker on both sides
    test = {s for s, p in parts.items() if p == {"test"}}
    assert {"arctic-slt", "praatio-bobby"} <= test
    # a development recording's labels never come from a system the set compares
    assert all(it.independent for it in speech_set if it.part == "dev")


def test_the_development_rule_picks_the_best_mean_on_dev_rows_only():
    def row(model, split, *v):
        return {"model": model, "split": split, **dict(zip(DEV_RULE, map(str, v)))}

    results = [row("voices-a", "unseen-dev", 0.7, 0.5, 0.5, 0.5),  # mean 0.55
               row("voices-b", "unseen-dev", 0.6, 0.6, 0.6, 0.6),  # mean 0.60
               row("voices-a", "unseen-test", 1, 1, 1, 1),  # test rows never count
               row("voices-c", "unseen-dev", 0.9, "nan", 0.9, 0.9),  # incomplete: skipped
               row("gated_mlp_utterance", "unseen-dev", 1, 1, 1, 1)]  # not a voices model
    best, scores = dev_choice(results)
    assert best == "voices-b" and set(scores) == {"voices-a", "voices-b"}
    assert scores["voices-a"] == pytest.approx(0.55)
    assert dev_choice([]) == (None, {})
