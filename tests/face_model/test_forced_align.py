"""Forced alignment of real GRID clips: the phones cover the audio, follow the words'
pronunciations and agree with GRID's own word times; transcripts that do not match the audio
(another sentence, a truncated one), empty ones and unknown words are refused by name."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from face_model import forced_align as fa
from face_model.corpus import PhoneSegment
from face_model.phones import PHONE_INDEX, phone_class
from face_model.transcripts import read_align
from groundwork.audio import read_wav, resample
from groundwork.errors import CorpusError

GRID = Path(__file__).resolve().parents[1] / "data" / "grid"
# the phones of each clip's words, from cmudict-en-us.dict
PRONUNCIATIONS = {
    "bbaf3s": "b ih n | b l uw | ae t | eh f | th r iy | s uw n",
    "lwbl7s": "l ey | hh w ay t | b ay | eh l | s eh v ah n | s uw n",
    "sgap1s": "s eh t | g r iy n | ae t | p iy | w ah n | s uw n",
}


def _clip(clip_id):
    y, sr = read_wav(GRID / "audio" / f"{clip_id}.wav")
    return y, sr, read_align(GRID / "align" / f"{clip_id}.align")


@pytest.fixture(scope="module")
def aligned():
    out = {}
    for clip_id in PRONUNCIATIONS:
        y, sr, transcript = _clip(clip_id)
        out[clip_id] = (y, sr, transcript,
                        fa.force_align(y, sr, transcript.text, source=f"{clip_id}.wav"))
    return out


def _contiguous(phones, duration_s):
    assert phones[0].start_s == 0.0
    assert all(a.end_s == b.start_s for a, b in zip(phones, phones[1:]))
    assert all(p.end_s > p.start_s for p in phones)
    assert abs(phones[-1].end_s - duration_s) < 1e-4
    assert all(p.phone in PHONE_INDEX for p in phones)
    assert not any(a.phone == b.phone == "sil" for a, b in zip(phones, phones[1:]))


@pytest.mark.parametrize("clip_id", sorted(PRONUNCIATIONS))
def test_a_grid_clip_aligns_to_its_own_transcript(aligned, clip_id):
    y, sr, transcript, result = aligned[clip_id]
    phones = fa.align_audio(y, sr, transcript.text, source=f"{clip_id}.wav")
    assert phones == result.phones
    _contiguous(phones, len(y) / sr)
    # silence around the sentence, the words' phones in order between
    assert phones[0].phone == phones[-1].phone == "sil"
    spoken = [p.phone for p in phones if p.phone != "sil"]
    assert spoken == PRONUNCIATIONS[clip_id].replace("|", "").split()
    # the transcript matches: the alignment scores near the free phone decode or above it
    assert result.gap > -fa.MAX_SCORE_GAP + 5
    assert result.speech_frames > 100  # of about 300 frames


@pytest.mark.parametrize("clip_id", sorted(PRONUNCIATIONS))
def test_the_word_times_agree_with_grids_alignment(aligned, clip_id):
    _, _, transcript, result = aligned[clip_id]
    assert [w for _, _, w in result.words] == transcript.text.split()
    ours = np.array([e for _, e, _ in result.words])
    grid = np.array([e for _, e, _ in transcript.words])
    # every word's end, so every boundary between two words (not the first word's start: GRID
    # puts it 0.1 s earlier in sgap1s and 0.31 s earlier, at the breath before it, in lwbl7s)
    assert np.abs(ours - grid).max() <= 0.1
    # the phones between two word ends are that word's
    for (s, e, word), pron in zip(result.words, PRONUNCIATIONS[clip_id].split("|")):
        inside = [p.phone for p in result.phones if s - 1e-9 <= p.start_s and p.end_s <= e + 1e-9
                  and p.phone != "sil"]
        assert inside == pron.split(), word


def test_audio_at_another_rate_gives_the_same_phones(aligned):
    y, sr, transcript, result = aligned["bbaf3s"]
    y44 = resample(y, sr_in=sr, sr_out=44100)
    phones = fa.align_audio(y44, 44100, transcript.text, source="bbaf3s.wav")
    _contiguous(phones, len(y44) / 44100)
    assert [p.phone for p in phones] == [p.phone for p in result.phones]
    assert max(abs(a.start_s - b.start_s) for a, b in zip(phones, result.phones)) <= 0.02


def _refusal(clip_id, text, result):
    n = result.speech_frames
    return (f"{clip_id}.wav: the transcript {text!r} does not match the audio (alignment score "
            f"{result.aligned_score / n:.1f} per speech frame against "
            f"{result.free_score / n:.1f} for free phone recognition; allowed gap "
            f"{fa.MAX_SCORE_GAP:g})")


@pytest.mark.parametrize("clip_id, text", [
    ("lwbl7s", "bin blue at f three soon"),  # another clip's sentence
    ("sgap1s", "bin blue at f three soon"),
    ("bbaf3s", "bin blue at"),  # its own first three words
    ("lwbl7s", "lay white by"),
    ("sgap1s", "set green at"),
])
def test_a_transcript_that_does_not_match_is_refused(clip_id, text):
    y, sr, _ = _clip(clip_id)
    result = fa.force_align(y, sr, text, source=f"{clip_id}.wav")
    assert result.gap < -fa.MAX_SCORE_GAP - 5  # far below the free decode
    with pytest.raises(CorpusError) as err:
        fa.align_audio(y, sr, text, source=f"{clip_id}.wav")
    assert str(err.value) == _refusal(clip_id, text, result)
    assert re.fullmatch(r"\S+: the transcript '.*' does not match the audio \(alignment score "
                        r"-\d+\.\d per speech frame against -\d+\.\d for free phone "
                        r"recognition; allowed gap \d+(\.\d+)?\)", str(err.value))


def test_a_transcript_no_path_goes_through_is_refused():
    y, sr, _ = _clip("bbaf3s")
    with pytest.raises(CorpusError) as err:
        fa.align_audio(y, sr, "lay white by l seven soon", source="bbaf3s.wav")
    assert str(err.value) == ("bbaf3s.wav: the transcript 'lay white by l seven soon' does not "
                              "match the audio (no alignment of its words to the audio was "
                              "found)")


@pytest.mark.parametrize("text, message", [
    ("", "x.wav: the transcript '' has no words; forced alignment needs the words spoken"),
    (" -- ,. ", "x.wav: the transcript ' -- ,. ' has no words; forced alignment needs the "
                "words spoken"),
    ("bin blue at f 3 soonish", "x.wav: words not in pocketsphinx's cmudict-en-us.dict: "
                                "['3', 'soonish']; write them as dictionary words (numbers "
                                "spelt out: 'two', not '2')"),
])
def test_an_empty_transcript_or_unknown_words_are_refused(text, message):
    y, sr, _ = _clip("bbaf3s")
    with pytest.raises(CorpusError) as err:
        fa.align_audio(y, sr, text, source="x.wav")
    assert str(err.value) == message


@pytest.mark.parametrize("y, shape", [(np.zeros(0), "(0,)"), (np.zeros((2, 80)), "(2, 80)"),
                                      (np.array([0.0, np.nan, 0.0]), "(3,)")])
def test_audio_that_cannot_be_aligned_is_refused(y, shape):
    with pytest.raises(CorpusError) as err:
        fa.align_audio(y, 16000, "bin", source="x.wav")
    assert str(err.value) == (f"x.wav: need mono audio with finite samples to align, got "
                              f"shape {shape}")


def test_a_failed_second_pass_is_redone_and_leaves_the_decoder_usable():
    # pocketsphinx 5.1.1's phone pass fails on sgap1s (issue #339): redone without bestpath
    y, sr, transcript = _clip("sgap1s")
    samples = fa.to_pcm16(y, sr)
    dec = fa.aligner()
    assert fa._two_passes(dec, samples.tobytes(), transcript.text) is None
    phones = fa.align(dec, samples, transcript.text)
    _contiguous(phones, len(samples) / fa.SAMPLE_RATE)
    spoken = [p.phone for p in phones if p.phone != "sil"]
    assert spoken == PRONUNCIATIONS["sgap1s"].replace("|", "").split()
    # after a failure the decoder is re-initialised: it aligns as a fresh one does
    y, sr, transcript = _clip("bbaf3s")
    samples = fa.to_pcm16(y, sr)
    assert fa.align(dec, samples, transcript.text) == fa.align(fa.aligner(), samples,
                                                                transcript.text)


def test_tidy_segments_fill_gaps_and_merge_silences():
    segs = [(0.1, 0.2, "b"), (0.2, 0.25, "sil"), (0.3, 0.4, "ih"), (0.4, 0.4, "n")]
    assert fa.tidy_segments(segs, 0.5) == [
        PhoneSegment(0.0, 0.1, "sil"), PhoneSegment(0.1, 0.2, "b"),
        PhoneSegment(0.2, 0.3, "sil"), PhoneSegment(0.3, 0.4, "ih"),
        PhoneSegment(0.4, 0.5, "sil")]


def test_phone_symbols_of_other_sets_map_to_the_44_classes():
    assert [phone_class(s) for s in ("AA1", "pau", "", "axr", "HH", "ix")] == [
        "aa", "sil", "sil", "er", "hh", "ih"]
    with pytest.raises(CorpusError, match=r"phone symbol 'qq' in x\.lab has no class among "
                                          r"the 44: iy ih"):
        phone_class("qq", source="x.lab")
