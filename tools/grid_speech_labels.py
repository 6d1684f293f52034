"""Phone labels for the GRID sentences of the real-speech evaluation set, made without either
phone recogniser the set compares: speaker s1 (``analysis/real_speech/grid/``, test part),
s26 (``grid-s26/``, development part) and s31 (``grid-s31/``, test part).

    python tools/grid_speech_labels.py [--set-dir DIR] [--align-dir DIR] [--more-dir DIR]
                                       [--check] [--measure]

Sentences (:data:`SPEAKERS`): of s1, every :data:`STEP`-th id, in sorted order and starting with
the first, of the 196 sentences of the built-in real corpus
(``face_model/real_faces/grid-s1/manifest.csv``): 40; of s26 and s31, every sentence of their
built-in real corpora (``face_model/real_faces/grid-s26``, ``grid-s31``): 10 each. s26 is the
speech set's development speaker of sentences and s31 a test speaker, as they are for the real
faces (``../shared/grid-more/README.md``). Their audio is not copied; the manifest points at each
corpus's FLAC (22,050 Hz) by a relative path and the set's loader resamples it to 16 kHz.

Labels (``label_source`` :data:`analysis.speech_set.GRID_WORDS`), for each sentence:

* the word boundaries are GRID's own (``<folder>/<id>.align``, GRID's word alignment copied
  unchanged, times in 1/25000 s, read by :func:`face_model.transcripts.read_align`); ``sil``,
  ``sp`` and gaps are ``sil``; the final silence is cut where the audio ends (GRID's last line
  ends at 2.98 s, the corpus's audio at 89/30 = 2.967 s);
* inside a word, its phones and their relative durations are espeak-ng's
  (:mod:`data_synth.espeak`, the default voice of :class:`data_synth.speech.SynthRequest`)
  speaking the word alone (``tools/espeak_word_phones.py``), scaled into GRID's span.
  espeak's silence before and after the word is dropped (before a word-initial stop it is the
  closure, which after a pause is silent in the recording too, so GRID's word starts at the
  release); a phone espeak reports with no duration of its own (the final /l/ of the letter
  "l", merged into its vowel) takes the second half of the phone before it;
* times are rounded to 0.1 ms (:func:`face_model.forced_align.tidy_segments`).

An ``.align`` whose entries end more than :data:`COVER_TOLERANCE_S` before the audio does, or
with a word running past the end of the audio, is refused naming the file.

Written: each speaker's ``<folder>/<id>.align`` (s1's from ``--align-dir``, s26's and s31's from
``--more-dir``'s ``<s26|s31>/align/`` (GRID's own layout, e.g. ``../shared/grid-more``); default:
the copies already in the set), ``<folder>/<id>.csv``, ``<folder>/NOTICE.md`` and the manifest's
rows of the three speakers (replaced; the other rows are kept as they are). ``--check`` writes
nothing: it regenerates every file in memory and exits 1 naming each that differs. ``--measure``
prints the labels' quality figures for s1 (the README's): /p b m/ segments against the real
lips' closed level, and viseme agreement per 30 fps frame with the built-in corpus's
pocketsphinx-aligned phones.
"""
from __future__ import annotations

import argparse
import csv
import io
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
for _p in (REPO, REPO / "tools"):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

from analysis.speech_set import (GRID_WORDS, MANIFEST, SET_DIR, read_labels,  # noqa: E402
                                 write_labels)
from espeak_word_phones import (file_differences, scale_into,  # noqa: E402
                                word_phones, write_or_check)  # noqa: F401 (word_phones: API)
from face_model.corpus import PhoneSegment, read_phones  # noqa: E402
from face_model.forced_align import tidy_segments  # noqa: E402
from face_model.transcripts import read_align  # noqa: E402
from groundwork.audio import read_wav  # noqa: E402
from groundwork.errors import CorpusError  # noqa: E402

from dataclasses import dataclass  # noqa: E402

REAL_FACES = REPO / "face_model" / "real_faces"
BUILTIN = REAL_FACES / "grid-s1"
STEP = 5  # every 5th sentence of the built-in corpus of s1, in sorted id order
SUBDIR = "grid"
SPEAKER = "grid-s1"  # the built-in real corpus's speaker id
COVER_TOLERANCE_S = 0.04  # one GRID video frame (25 fps): how far short of the audio it may end
FPS = 30
SOURCE = ('the GRID corpus, M. Cooke, J. Barker, S. Cunningham, X. Shao (2006), "An audio-visual\n'
          'corpus for speech perception and automatic speech recognition", *JASA*\n'
          '120(5):2421–2424; released on Zenodo (record 3625687) under the Creative Commons Attribution 4.0 licence\n'
          '(https://creativecommons.org/licenses/by/4.0/).')


@dataclass(frozen=True)
class GridSpeaker:
    """One GRID speaker of the set: its speaker id, built-in corpus, folder in the set, every
    ``step``-th sentence of the corpus (sorted ids), its part and a line on who it is."""
    speaker: str
    corpus: Path
    subdir: str
    step: int
    part: str
    who: str

    @property
    def short(self) -> str:
        return self.speaker.split("-", 1)[1]  # s1, s26, s31

    @property
    def licence(self) -> str:
        return ("GRID corpus (Cooke, Barker, Cunningham & Shao 2006), CC BY 4.0 "
                f"({self.subdir}/NOTICE.md)")


SPEAKERS = (
    GridSpeaker(SPEAKER, BUILTIN, SUBDIR, STEP, "test", "the real speaker"),
    GridSpeaker("grid-s26", REAL_FACES / "grid-s26", "grid-s26", 1, "dev",
                "a man; the development speaker of sentences, never trained on"),
    GridSpeaker("grid-s31", REAL_FACES / "grid-s31", "grid-s31", 1, "test",
                "a woman; a test speaker, never trained on"),
)
LICENCE = SPEAKERS[0].licence


def notice(sp: GridSpeaker, n: int) -> str:
    """The ``NOTICE.md`` beside a speaker's labels (``n`` sentences)."""
    which = (f"every {sp.step}th sentence of the built-in real corpus "
             f"`face_model/real_faces/{sp.corpus.name}`" if sp.step > 1 else
             f"every sentence of the built-in real corpus `face_model/real_faces/{sp.corpus.name}`")
    return f"""# GRID speaker {sp.short}: word alignments and derived phone labels

The `.align` files here are the GRID corpus's own word alignments of {n} sentences of speaker
{sp.short} ({sp.who}; {which}), copied unchanged: one `start end word` per line, times in 1/25000 s,
`sil` and `sp` silence. In the real-speech set they are the `{sp.part}` part.

The `.csv` files are **derived (modified) labels** made from them by
`tools/grid_speech_labels.py`: GRID's word boundaries kept, `sil` and `sp` written `sil`, the
final silence cut where the audio ends, and each word divided into its phones (the project's 44
classes) with the relative durations espeak-ng gives the word spoken alone, scaled into GRID's
word span. The audio they label is the built-in corpus's FLAC
(`face_model/real_faces/{sp.corpus.name}/audio/<id>.flac`: GRID's audio track resampled to
22,050 Hz; see `face_model/real_faces/{sp.corpus.name}/NOTICE.md`).

Source: {SOURCE}
"""


def subset_ids(corpus_dir=BUILTIN, step: int = STEP) -> list[str]:
    """The sentences labelled: every ``step``-th id of the corpus, sorted, from the first."""
    with open(Path(corpus_dir) / "manifest.csv", newline="", encoding="utf-8") as f:
        ids = sorted(row["utt_id"] for row in csv.DictReader(f))
    return ids[::step]


def sentence_labels(align_path, duration_s: float, phones: dict) -> list[PhoneSegment]:
    """Contiguous phone segments over ``[0, duration_s]`` from GRID's words and ``phones``.

    Raises
    ------
    CorpusError
        Naming ``align_path``: its entries stop more than :data:`COVER_TOLERANCE_S` before the
        audio ends, run more than 0.1 s past it, or a word ends after the audio.
    """
    tr = read_align(align_path)
    tr.check_duration(duration_s)
    if tr.end_s < duration_s - COVER_TOLERANCE_S:
        raise CorpusError(f"{align_path}: its word alignment ends at {tr.end_s:.3f} s but the "
                          f"audio lasts {duration_s:.3f} s; it must cover the audio (allowed: "
                          f"up to {COVER_TOLERANCE_S:g} s short)")
    segs = []
    for start, end, word in tr.words:
        if end > duration_s + 1e-9:
            raise CorpusError(f"{align_path}: the word {word!r} ends at {end:.3f} s, after "
                              f"the audio ({duration_s:.3f} s)")
        segs += scale_into(phones[word], start, end)
    out = tidy_segments(segs, duration_s)
    if sum(s.phone != "sil" for s in out) != len(segs):
        raise CorpusError(f"{align_path}: a phone shorter than 0.1 ms after scaling")
    return out


def _duration(wav) -> float:
    y, sr = read_wav(wav)
    return len(y) / sr


def _csv_bytes(segs) -> bytes:
    with tempfile.TemporaryDirectory() as tmp:  # write_labels: the set's one writer
        return write_labels(Path(tmp) / "x.csv", segs).read_bytes()


def manifest_rows(set_dir, ids, aligns: dict, sp: GridSpeaker = SPEAKERS[0]) -> list[dict]:
    """The manifest rows of one speaker's GRID sentences (``aligns``: id → .align path)."""
    rows = []
    for utt in ids:
        wav = os.path.relpath(sp.corpus / "audio" / f"{utt}.flac", set_dir)
        rows.append({"id": f"grid_{sp.short}_{utt}", "wav": Path(wav).as_posix(),
                     "labels": f"{sp.subdir}/{utt}.csv", "speaker": sp.speaker,
                     "label_source": GRID_WORDS,
                     "label_origin": f"{sp.subdir}/{utt}.align", "part": sp.part,
                     "transcript": read_align(aligns[utt]).text, "licence": sp.licence})
    return rows


def _manifest_bytes(set_dir: Path, grid_rows: dict) -> bytes:
    """The manifest with each speaker's rows (``grid_rows``: speaker → rows) in place of its
    old ones (at the first old row's place, else at the end), every other row as it was."""
    with open(set_dir / MANIFEST, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        columns = reader.fieldnames
        rows = list(reader)
    for speaker, new in grid_rows.items():
        ours = [i for i, r in enumerate(rows) if r["speaker"] == speaker]
        at = ours[0] if ours else len(rows)
        rows = rows[:at] + new + [r for r in rows[at:] if r["speaker"] != speaker]
    buf = io.StringIO()
    w = csv.DictWriter(buf, columns, lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue().encode("utf-8")


def build(set_dir=SET_DIR, align_dir=None, more_dir=None) -> dict[str, bytes]:
    """Every file the tool owns, ``{path relative to the set: contents}``, made in memory.
    ``align_dir``: s1's ``.align`` files; ``more_dir``: a folder with ``<s26|s31>/align/``
    (default: the copies in the set, for each)."""
    set_dir = Path(set_dir)
    files, grid_rows, plan = {}, {}, []
    for sp in SPEAKERS:
        if sp.speaker == SPEAKER:
            src = Path(align_dir) if align_dir else set_dir / sp.subdir
        else:
            src = Path(more_dir) / sp.short / "align" if more_dir else set_dir / sp.subdir
        ids = subset_ids(sp.corpus, sp.step)
        plan.append((sp, ids, {u: src / f"{u}.align" for u in ids}))
    phones = word_phones(w for _, ids, aligns in plan for u in ids
                         for w in read_align(aligns[u]).text.split())
    for sp, ids, aligns in plan:
        for utt in ids:
            files[f"{sp.subdir}/{utt}.align"] = aligns[utt].read_bytes()
            segs = sentence_labels(aligns[utt], _duration(sp.corpus / "audio" / f"{utt}.flac"),
                                   phones)
            files[f"{sp.subdir}/{utt}.csv"] = _csv_bytes(segs)
        files[f"{sp.subdir}/NOTICE.md"] = notice(sp, len(ids)).encode("utf-8")
        grid_rows[sp.speaker] = manifest_rows(set_dir, ids, aligns, sp)
    files[MANIFEST] = _manifest_bytes(set_dir, grid_rows)
    return files


def differences(set_dir=SET_DIR, files=None) -> list[str]:
    """The files (relative to the set) that differ from ``files`` (default: :func:`build`),
    and any file in a speaker's folder the tool would not write."""
    files = build(set_dir) if files is None else files
    out = []
    for sp in SPEAKERS:
        out += [d for d in file_differences(set_dir, sp.subdir, files) if d not in out]
    return out


# -- quality of the labels --------------------------------------------------------------------
def _share(flags) -> str:
    flags = np.asarray(flags, dtype=bool)
    return f"{flags.mean():.1%} ({int(flags.sum())}/{len(flags)})" if len(flags) else "n/a"


def closed_level(opening) -> float:
    """The closed level of one clip's real lips, P10 + 0.10 × (P90 − P10) of its openings: the
    lowest decile is the closed floor of running speech, a tenth of the ordinary range the
    margin for landmark jitter (a measurement of the labels, fixed before they were compared)."""
    p10, p90 = np.percentile(np.asarray(opening, dtype=np.float64), [10, 90])
    return float(p10 + 0.10 * (p90 - p10))


def measure(set_dir=SET_DIR) -> dict:
    """Both label sets against the real lips and each other, pooled over the sentences.

    Closed level per clip: :func:`closed_level` of the clip's own opening
    (:func:`face_model.layout.mouth_opening` of the glasses-aligned markers),
    P10 + 0.10 × (P90 − P10). A segment *reaches* it when the opening is at or below it in a
    frame overlapping the segment (:func:`analysis.speech_eval.segment_contact`); *at centre*
    when the opening interpolated at the segment's centre is. Visemes per 30 fps frame
    (frame k at k/30 s): agreement over all frames and over frames where either set has speech.
    """
    # the measurement's own imports: building and checking the labels need none of them
    from analysis.speech_eval import VOWELS, phone_frames, segment_contact, viseme_index
    from face_model.alignment import align_markers
    from face_model.layout import mouth_opening
    from face_model.phones import BILABIALS, PHONE_INDEX

    set_dir = Path(set_dir)
    acc = {k: [] for k in ("grid_bil", "ps_bil", "grid_bil_c", "ps_bil_c", "grid_vow", "ps_vow",
                           "vis_all", "vis_speech", "ph_all", "ph_speech")}
    ids, levels, spans = subset_ids(), [], []  # s1's sentences
    for utt in ids:
        duration = _duration(BUILTIN / "audio" / f"{utt}.flac")
        ours = read_labels(set_dir / SUBDIR / f"{utt}.csv", duration)
        ps = read_phones(BUILTIN / "phones" / f"{utt}.csv", duration)
        opening = mouth_opening(align_markers(np.load(BUILTIN / "markers" / f"{utt}.npy")))
        thr = closed_level(opening)
        levels.append(thr)
        spans.append(np.percentile(opening, 90) - np.percentile(opening, 10))
        for name, segs in (("grid", ours), ("ps", ps)):
            bil = segment_contact(opening, FPS, segs, BILABIALS, thr)
            acc[f"{name}_bil"] += list(bil.met)
            acc[f"{name}_bil_c"] += list(bil.centre_opening <= thr)
            acc[f"{name}_vow"] += list(segment_contact(opening, FPS, segs, VOWELS, thr).met)
        times = np.arange(len(opening)) / FPS
        a, b = phone_frames(ours, times), phone_frames(ps, times)
        speech = (a != PHONE_INDEX["sil"]) | (b != PHONE_INDEX["sil"])
        acc["vis_all"] += list(viseme_index(a) == viseme_index(b))
        acc["vis_speech"] += list((viseme_index(a) == viseme_index(b))[speech])
        acc["ph_all"] += list(a == b)
        acc["ph_speech"] += list((a == b)[speech])
    return {"sentences": len(ids), "frames": len(acc["vis_all"]),
            "level_px": (float(np.median(levels)), float(np.min(levels)), float(np.max(levels))),
            "p10_p90_px": float(np.median(spans)), **{k: _share(v) for k, v in acc.items()}}


def print_measure(m: dict, out=sys.stdout) -> None:
    lv = m["level_px"]
    print(f"{m['sentences']} sentences, {m['frames']} frames; closed level per clip P10 + 0.10 x "
          f"(P90 - P10): median {lv[0]:.2f} px (range {lv[1]:.2f}-{lv[2]:.2f}), median P90 - "
          f"P10 {m['p10_p90_px']:.2f} px", file=out)
    print("| | GRID words + espeak-ng | pocketsphinx alignment |\n|---|---|---|", file=out)
    for label, key in (("/p b m/ segments reaching the closed level", "bil"),
                       ("/p b m/ segments closed at their centre", "bil_c"),
                       ("vowel segments reaching the closed level (control)", "vow")):
        print(f"| {label} | {m['grid_' + key]} | {m['ps_' + key]} |", file=out)
    print(f"| viseme agreement per frame, all frames | {m['vis_all']} |\n"
          f"| viseme agreement, frames with speech in either | {m['vis_speech']} |\n"
          f"| phone agreement, all frames | {m['ph_all']} |\n"
          f"| phone agreement, frames with speech in either | {m['ph_speech']} |", file=out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--set-dir", type=Path, default=SET_DIR)
    p.add_argument("--align-dir", type=Path, default=None,
                   help="folder of GRID s1 .align files (default: the copies in the set)")
    p.add_argument("--more-dir", type=Path, default=None,
                   help="folder with GRID's s26/align and s31/align (e.g. ../shared/grid-more; "
                        "default: the copies in the set)")
    p.add_argument("--check", action="store_true", help="compare with the shipped files")
    p.add_argument("--measure", action="store_true", help="print the labels' quality figures")
    args = p.parse_args(argv)
    if args.measure:
        print_measure(measure(args.set_dir))
        return 0
    try:
        files = build(args.set_dir, args.align_dir, args.more_dir)
    except (CorpusError, FileNotFoundError) as exc:
        print(f"grid_speech_labels: {exc}", file=sys.stderr)
        return 2
    if args.check:
        differ = differences(args.set_dir, files)
        for rel in differ:
            print(f"{args.set_dir / rel}: differs from what the tool makes", file=sys.stderr)
        print(f"{len(files)} files checked, {len(differ)} differ")
        return 1 if differ else 0
    for sp in SPEAKERS:
        (args.set_dir / sp.subdir).mkdir(exist_ok=True)
    return write_or_check(args.set_dir, SUBDIR, files, check=False)


if __name__ == "__main__":
    sys.exit(main())
