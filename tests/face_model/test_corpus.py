"""Reading and validating a corpus folder: a corpus loads whole or fails naming the file.

Every damaged corpus is a private copy of the small session corpus (``corpus_copy``).
"""
from __future__ import annotations

import csv
import re
import wave
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.signal import resample_poly

from face_model.corpus import (
    MANIFEST_COLUMNS,
    PhoneSegment,
    Utterance,
    WordSegment,
    corpus_hash,
    load_corpus,
    read_words,
    words_path,
    write_manifest,
    write_utterance,
    write_words,
)
from face_model.layout import N_MARKERS
from face_model.phones import PHONE_INDEX
from groundwork.errors import CorpusError

UTT = "s00_neutral_001"  # the utterance a test damages (manifest line 3)
LINE = 3


def _rows(root: Path) -> list[dict]:
    with open(root / "manifest.csv", newline="") as f:
        return list(csv.DictReader(f))


def _write_rows(root: Path, rows: list[dict]) -> None:
    with open(root / "manifest.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]), lineterminator="\n")
        w.writeheader()
        w.writerows(rows)


def _edit_row(root: Path, utt_id: str, **changes) -> None:
    rows = _rows(root)
    for r in rows:
        if r["utt_id"] == utt_id:
            r.update({k: str(v) for k, v in changes.items()})
    _write_rows(root, rows)


def _pcm16(path: Path, samples: np.ndarray, sr: int, channels: int = 1) -> None:
    ints = np.clip(np.round(np.asarray(samples) * 32767), -32768, 32767).astype("<i2")
    with wave.open(str(path), "wb") as w:
        w.setnchannels(channels)
        w.setsampwidth(2)
        w.setframerate(sr)
        w.writeframes(ints.tobytes())


def _read_pcm16(path: Path) -> tuple[np.ndarray, int]:
    with wave.open(str(path), "rb") as w:
        return np.frombuffer(w.readframes(w.getnframes()), "<i2") / 32768.0, w.getframerate()


def _where(path: Path) -> str:
    return re.escape(str(path))


# -- a valid corpus ------------------------------------------------------------------------------
def test_valid_corpus_loads_with_checked_arrays(small_corpus, small_corpus_dir):
    rows = _rows(small_corpus_dir)
    assert list(rows[0]) == list(MANIFEST_COLUMNS)
    assert [u.utt_id for u in small_corpus.utterances] == [r["utt_id"] for r in rows]
    assert len(small_corpus) == 12
    assert small_corpus.n_frames == sum(int(r["n_frames"]) for r in rows)
    for u in small_corpus.utterances:
        assert u.markers.dtype == np.float32 and u.markers.shape == (u.n_frames, N_MARKERS, 2)
        assert u.audio.dtype == np.float32 and u.audio.ndim == 1
        assert np.abs(u.audio).max() <= 1.0
        assert (u.fps, u.sample_rate) == (30, 22050)
        assert all(p.phone in PHONE_INDEX for p in u.phones)
        ppf = u.phone_per_frame()
        assert ppf.shape == (u.n_frames,) and ppf.dtype == np.int64
        assert ppf[0] == ppf[-1] == PHONE_INDEX["sil"]
    assert small_corpus[UTT].expression == "neutral"
    assert {len(small_corpus.by_expression(e)) for e in ("neutral", "smile", "sad")} == {4}
    with pytest.raises(KeyError, match="'s09_neutral_000' is not in the corpus"):
        small_corpus["s09_neutral_000"]


def test_phone_per_frame_follows_the_segments():
    u = Utterance(
        "u", "s00", "neutral", "", 30, 22050, np.zeros(22050, np.float32),
        np.zeros((9, N_MARKERS, 2), np.float32),
        [PhoneSegment(0.0, 0.1, "sil"), PhoneSegment(0.1, 0.2, "m"), PhoneSegment(0.2, 0.25, "aa")])
    # Frames at 0, 1/30, ..., 8/30 s: 0–2 sil, 3–5 m, 6–7 aa (7/30 < 0.25), 8 outside → sil.
    expected = ["sil"] * 3 + ["m"] * 3 + ["aa"] * 2 + ["sil"]
    assert u.phone_per_frame().tolist() == [PHONE_INDEX[p] for p in expected]


def test_write_then_load_round_trips_an_utterance(tmp_path, rng):
    markers = (rng.uniform(0, 400, (12, N_MARKERS, 2))).astype(np.float32)
    audio = 0.1 * rng.standard_normal(12 * 735)
    phones = [PhoneSegment(0.0, 0.1, "sil"), PhoneSegment(0.1, 0.3, "iy"),
              PhoneSegment(0.3, 0.4, "sil")]
    rel = write_utterance(tmp_path, utt_id="x", audio=audio, sr=22050, markers=markers,
                          phones=phones)
    write_manifest(tmp_path, [{"utt_id": "x", "speaker": "s00", "expression": "smile",
                               "text": "a, \"quoted\" text", "n_frames": 12, "fps": 30,
                               "sample_rate": 22050, **rel}])
    u = load_corpus(tmp_path).utterances[0]
    assert np.array_equal(u.markers, markers)
    np.testing.assert_allclose(u.audio, audio, atol=1.0 / 32767)
    assert u.phones == phones and u.text == "a, \"quoted\" text"


def test_corpus_hash_is_stable_and_sees_damage(small_corpus_dir, corpus_copy):
    assert corpus_hash(corpus_copy) == corpus_hash(small_corpus_dir)
    path = corpus_copy / "markers" / f"{UTT}.npy"
    m = np.load(path)
    m[0, 0, 0] += 0.5
    np.save(path, m)
    assert corpus_hash(corpus_copy) != corpus_hash(small_corpus_dir)
    # the manifest is read by the one reader: a missing file column is named
    _write_rows(corpus_copy, [{k: v for k, v in r.items() if k != "markers"}
                              for r in _rows(corpus_copy)])
    with pytest.raises(CorpusError, match=r"manifest\.csv: missing columns \['markers'\]"):
        corpus_hash(corpus_copy)


# -- the five damaged files of the acceptance list -------------------------------------------
def test_truncated_wav_is_refused(corpus_copy):
    path = corpus_copy / "audio" / f"{UTT}.wav"
    data = path.read_bytes()
    path.write_bytes(data[:-1000])
    with pytest.raises(CorpusError, match=_where(path) + r": truncated WAV: header declares "
                                          r"\d+ samples per channel, the file holds \d+"):
        load_corpus(corpus_copy)


def test_markers_with_a_nan_are_refused(corpus_copy):
    path = corpus_copy / "markers" / f"{UTT}.npy"
    m = np.load(path)
    m[17, 52, 1] = np.nan
    np.save(path, m)
    with pytest.raises(CorpusError, match=_where(path) + r": 1 non-finite values \(NaN/inf\), "
                                          r"the first at frame 17, marker 52"):
        load_corpus(corpus_copy)


@pytest.mark.parametrize("shape_change", ["markers", "coordinates", "flat"])
def test_markers_of_the_wrong_shape_are_refused(corpus_copy, shape_change):
    path = corpus_copy / "markers" / f"{UTT}.npy"
    m = np.load(path)
    bad = {"markers": m[:, :78], "coordinates": np.concatenate([m, m[..., :1]], axis=2),
           "flat": m.reshape(len(m), -1)}[shape_change]
    np.save(path, bad)
    with pytest.raises(CorpusError, match=_where(path) + r": markers must have shape "
                       r"\(n_frames, 79, 2\), got " + re.escape(str(bad.shape))):
        load_corpus(corpus_copy)


def test_phone_file_with_an_unknown_phone_is_refused(corpus_copy):
    path = corpus_copy / "phones" / f"{UTT}.csv"
    lines = path.read_text().splitlines()
    start, end, _ = lines[3].split(",")
    lines[3] = f"{start},{end},zz"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(CorpusError, match=_where(path) + r", line 4: unknown phone 'zz'; allowed "
                                          r"are the 44 classes"):
        load_corpus(corpus_copy)


@pytest.mark.parametrize("column", ["audio", "markers", "phones"])
def test_manifest_row_pointing_to_a_missing_file_is_refused(corpus_copy, column):
    ext = {"audio": "wav", "markers": "npy", "phones": "csv"}[column]
    _edit_row(corpus_copy, UTT, **{column: f"{column}/missing.{ext}"})
    manifest = corpus_copy / "manifest.csv"
    with pytest.raises(CorpusError, match=_where(manifest) + f", line {LINE}: {column} file "
                       + _where(corpus_copy / column / f"missing.{ext}") + " not found"):
        load_corpus(corpus_copy)


def test_deleted_file_is_refused(corpus_copy):
    path = corpus_copy / "phones" / f"{UTT}.csv"
    path.unlink()
    with pytest.raises(CorpusError, match=r"line 3: phones file " + _where(path) + " not found"):
        load_corpus(corpus_copy)


# -- audio format ----------------------------------------------------------------------------
def test_stereo_wav_is_refused(corpus_copy):
    path = corpus_copy / "audio" / f"{UTT}.wav"
    y, sr = _read_pcm16(path)
    _pcm16(path, np.repeat(y, 2), sr, channels=2)
    with pytest.raises(CorpusError, match=_where(path) + ": 2 channels; the corpus format "
                                          "requires mono audio"):
        load_corpus(corpus_copy)


def _to_16k(corpus: Path) -> tuple[Path, np.ndarray]:
    path = corpus / "audio" / f"{UTT}.wav"
    y, sr = _read_pcm16(path)
    assert sr == 22050
    _pcm16(path, resample_poly(y, 320, 441), 16000)
    _edit_row(corpus, UTT, sample_rate=16000)
    return path, y


def test_16khz_audio_is_refused_with_its_rate_named(corpus_copy):
    path, _ = _to_16k(corpus_copy)
    with pytest.raises(CorpusError, match=_where(path) + r": sample rate 16000 Hz gives no "
                                          r"integer hop at 30 fps; allowed: 22050, .*resample_to="):
        load_corpus(corpus_copy)


def test_16khz_audio_is_resampled_when_asked(corpus_copy, small_corpus):
    _, original = _to_16k(corpus_copy)
    corpus = load_corpus(corpus_copy, resample_to=22050)
    u = corpus[UTT]
    assert u.sample_rate == 22050
    assert abs(len(u.audio) - len(original)) <= 2
    n = min(len(u.audio), len(original))
    # Speech below 8 kHz survives the round trip 22050 → 16000 → 22050 Hz.
    err = u.audio[:n] - original[:n]
    assert np.sqrt(np.mean(err**2)) < 0.1 * np.sqrt(np.mean(original**2))
    assert np.array_equal(u.markers, small_corpus[UTT].markers)
    # The untouched utterances are as before.
    other = "s00_smile_002"
    assert np.array_equal(corpus[other].audio, small_corpus[other].audio)


def test_manifest_rate_disagreeing_with_the_file_is_refused(corpus_copy):
    _edit_row(corpus_copy, UTT, sample_rate=44100)
    path = corpus_copy / "audio" / f"{UTT}.wav"
    with pytest.raises(CorpusError, match=_where(path) + ": sample rate 22050 Hz, the manifest "
                                          "says 44100"):
        load_corpus(corpus_copy)


# -- audio and markers agreeing ----------------------------------------------------------------
def _drop_last_frames(corpus_dir, n_drop: int) -> int:
    """Cut ``n_drop`` frames off UTT's markers (manifest kept consistent); return the old count."""
    mpath = corpus_dir / "markers" / f"{UTT}.npy"
    m = np.load(mpath)
    np.save(mpath, m[:-n_drop])
    _edit_row(corpus_dir, UTT, n_frames=len(m) - n_drop)
    return len(m)


def test_markers_two_frames_short_of_the_audio_are_refused(corpus_copy):
    n = _drop_last_frames(corpus_copy, 2)
    apath = corpus_copy / "audio" / f"{UTT}.wav"
    with pytest.raises(CorpusError, match=_where(apath) + rf": audio lasts [\d.]+ s = "
                       rf"{n}\.00 frames, but {UTT}\.npy has {n - 2} frames \(more than "
                       r"one frame apart\)"):
        load_corpus(corpus_copy)


def test_audio_two_frames_longer_than_the_markers_is_refused(corpus_copy):
    apath = corpus_copy / "audio" / f"{UTT}.wav"
    y, sr = _read_pcm16(apath)
    _pcm16(apath, np.r_[y, np.zeros(2 * sr // 30 + 10)], sr)
    with pytest.raises(CorpusError, match=_where(apath) + r": audio lasts .* \(more than one "
                                          r"frame apart\)"):
        load_corpus(corpus_copy)


def test_audio_and_markers_one_frame_apart_are_accepted(corpus_copy):
    n = _drop_last_frames(corpus_copy, 1)
    assert load_corpus(corpus_copy)[UTT].n_frames == n - 1


def test_marker_count_disagreeing_with_the_manifest_is_refused(corpus_copy):
    mpath = corpus_copy / "markers" / f"{UTT}.npy"
    n = len(np.load(mpath))
    _edit_row(corpus_copy, UTT, n_frames=n + 5)
    with pytest.raises(CorpusError, match=_where(mpath) + f": {n} frames, the manifest says "
                                          f"{n + 5}"):
        load_corpus(corpus_copy)


@pytest.mark.parametrize("dtype", [np.int16, np.int32, np.int64])
def test_integer_markers_are_refused(corpus_copy, dtype):
    path = corpus_copy / "markers" / f"{UTT}.npy"
    np.save(path, np.round(np.load(path)).astype(dtype))
    with pytest.raises(CorpusError, match=_where(path) + r": markers must be float32 "
                       rf"\(or float64\), got dtype {np.dtype(dtype).name}"):
        load_corpus(corpus_copy)


def test_float64_markers_are_accepted_as_float32(corpus_copy, small_corpus):
    path = corpus_copy / "markers" / f"{UTT}.npy"
    np.save(path, np.load(path).astype(np.float64))
    u = load_corpus(corpus_copy)[UTT]
    assert u.markers.dtype == np.float32
    assert np.array_equal(u.markers, small_corpus[UTT].markers)


# -- manifest and phone-file problems -----------------------------------------------------------
def test_manifest_problems_are_named(corpus_copy):
    manifest = corpus_copy / "manifest.csv"
    _edit_row(corpus_copy, UTT, expression="angry")
    with pytest.raises(CorpusError, match=_where(manifest) + ", line 3: expression 'angry'; "
                                          "allowed: neutral, smile, sad"):
        load_corpus(corpus_copy)
    _edit_row(corpus_copy, UTT, expression="neutral", fps=25)
    with pytest.raises(CorpusError, match=_where(manifest) + ", line 3: fps 25; the corpus "
                                          "format requires 30"):
        load_corpus(corpus_copy)
    rows = _rows(corpus_copy)
    rows[1]["fps"] = "30"
    rows[2]["utt_id"] = rows[1]["utt_id"]
    _write_rows(corpus_copy, rows)
    with pytest.raises(CorpusError, match=_where(manifest) + f", line 4: duplicate utt_id "
                                          f"'{UTT}'"):
        load_corpus(corpus_copy)
    _write_rows(corpus_copy, [{k: v for k, v in r.items() if k != "phones"} for r in rows])
    with pytest.raises(CorpusError, match=_where(manifest) + r": missing columns \['phones'\]"):
        load_corpus(corpus_copy)
    manifest.unlink()
    with pytest.raises(CorpusError, match=_where(manifest) + ": manifest not found"):
        load_corpus(corpus_copy)


@pytest.mark.parametrize("line,problem", [
    ("0.50000,0.40000,aa", r"line 3: need 0 <= start_s < end_s, got 0\.5, 0\.4"),
    ("abc,0.40000,aa", r"line 3: times must be numbers, got 'abc'"),
])
def test_bad_phone_times_are_refused(corpus_copy, line, problem):
    path = corpus_copy / "phones" / f"{UTT}.csv"
    lines = path.read_text().splitlines()
    lines[2] = line
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(CorpusError, match=_where(path) + ", " + problem):
        load_corpus(corpus_copy)


def test_phones_beyond_the_audio_are_refused(corpus_copy):
    path = corpus_copy / "phones" / f"{UTT}.csv"
    text = path.read_text().rstrip("\n")
    path.write_text(text + "\n99.00000,100.00000,sil\n")
    with pytest.raises(CorpusError, match=_where(path) + r": last phone ends at 100\.000 s, after "
                                          r"the audio \([\d.]+ s\)"):
        load_corpus(corpus_copy)


# -- words/<utt_id>.csv: the words' times, optional ----------------------------------------------
def _spread_words(u: Utterance) -> list[WordSegment]:
    """The utterance's text as words, one after another between 10 % and 90 % of its audio."""
    said = u.text.split()
    d = len(u.audio) / u.sample_rate
    edges = np.round(np.linspace(0.1 * d, 0.9 * d, len(said) + 1), 5)
    return [WordSegment(float(a), float(b), w) for a, b, w in zip(edges[:-1], edges[1:], said)]


def test_a_corpus_without_words_loads_with_none(small_corpus):
    assert all(u.words is None for u in small_corpus.utterances)


def test_words_written_are_read_back_by_the_corpus_reader(corpus_copy, small_corpus):
    words = _spread_words(small_corpus[UTT])
    assert write_words(corpus_copy, UTT, words) == f"words/{UTT}.csv"
    assert words_path(corpus_copy, UTT).is_file()
    corpus = load_corpus(corpus_copy)
    assert corpus[UTT].words == tuple(words)
    assert " ".join(w.word for w in corpus[UTT].words) == corpus[UTT].text
    assert all(u.words is None for u in corpus.utterances if u.utt_id != UTT)
    assert corpus_hash(corpus_copy) == corpus_hash(corpus_copy)  # the manifest is unchanged


_WORD = st.text(alphabet="abcdefghijklmnopqrstuvwxyz'", min_size=1, max_size=8).filter(
    lambda w: w not in ("sil", "sp"))


@given(words=st.lists(_WORD, min_size=1, max_size=8),
       cuts=st.lists(st.integers(1, 40000), min_size=20, max_size=20, unique=True),
       gaps=st.lists(st.booleans(), min_size=8, max_size=8))
def test_any_words_file_round_trips_through_the_writer_and_reader(tmp_path_factory, words, cuts,
                                                                  gaps):
    root = tmp_path_factory.mktemp("words")
    edges = sorted(c / 10000 for c in cuts)  # seconds, 0.1 ms apart at least
    timed, k = [], 0
    for i, w in enumerate(words):
        k += gaps[i]  # a pause between words where it is true
        timed.append(WordSegment(edges[k], edges[k + 1], w))
        k += 1
    write_words(root, "u", timed)
    assert read_words(words_path(root, "u"), duration_s=4.0,
                      text=" ".join(words).upper()) == tuple(timed)


_BAD_WORDS = [  # (file after the header line, the line named, the problem, what is allowed)
    (None, "start,end,word", r", line 1: header 'start,end,word'; allowed: start_s,end_s,word"),
    ("abc,0.40000,{0}", None, r", line 2: times 'abc', '0\.40000'; allowed: numbers of seconds with "
                              r"0 <= start_s < end_s"),
    ("0.50000,0.40000,{0}", None, r", line 2: times '0\.50000', '0\.40000'; allowed: numbers of "
                                  r"seconds with 0 <= start_s < end_s"),
    ("0.10000,0.20000,{0}\n0.15000,0.30000,{1}", None,
     r", line 3: starts at 0\.15 s, before the previous word ends \(0\.2 s\); allowed: words in "
     r"time order, not overlapping"),
    ("0.00000,0.10000,sil\n0.10000,0.20000,{0}", None,
     r", line 2: word 'sil'; allowed: one word per line, silences \(sil, sp\) left out"),
    ("0.10000,0.20000", None, r", line 2: 2 fields '0\.10000,0\.20000'; allowed: 3, "
                              r"start_s,end_s,word"),
    ("0.10000,0.20000,{0}\n99.00000,99.50000,{1}", None,
     r", line 3: word '.+' ends at 99\.5 s, after the audio \([\d.]+ s\); allowed: up to 0\.1 s "
     r"after its end"),
    ("0.10000,0.20000,{1}", None, r", line 2: word '.+', but the manifest's text '.+' has word 1 "
                                  r"'.+' there; allowed: the text's words in order, one per line"),
    ("0.10000,0.20000,{0}", None, r": 1 words, but the manifest's text '.+' has \d+; allowed: "
                                  r"the text's words in order, one per line"),
    ("", None, r": no words under the header; allowed: one line per word spoken"),
]


@pytest.mark.parametrize("body, header, problem", _BAD_WORDS,
                         ids=["header", "text time", "end before start", "overlap", "silence",
                              "two fields", "after the audio", "another word", "too few words",
                              "no words"])
def test_a_malformed_words_file_is_refused_in_one_line_naming_it(corpus_copy, small_corpus, body,
                                                                 header, problem):
    u = small_corpus[UTT]
    said = u.text.split()
    assert len(said) >= 2 and said[0].lower() != said[1].lower()
    path = words_path(corpus_copy, UTT)
    write_words(corpus_copy, UTT, _spread_words(u))
    lines = path.read_text().splitlines()
    if header is not None:
        path.write_text("\n".join([header, *lines[1:]]) + "\n")
    else:
        path.write_text(lines[0] + "\n" + body.format(*said) + "\n")
    with pytest.raises(CorpusError, match=_where(path) + problem) as err:
        load_corpus(corpus_copy)
    assert "\n" not in str(err.value)
