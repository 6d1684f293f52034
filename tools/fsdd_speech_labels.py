"""The FSDD part of the real-speech evaluation set (``analysis/real_speech/fsdd/``): spoken digits
of six real speakers, copied unchanged, with phone labels made without either phone recogniser
the set compares.

    python tools/fsdd_speech_labels.py [--set-dir DIR] [--source DIR] [--check] [--measure]

Source: the Free Spoken Digit Dataset (``--source``, default ``../shared/fsdd`` beside the
repository: ``recordings/{digit}_{speaker}_{index}.wav``, mono 8 kHz PCM16, CC BY-SA 4.0).

Subset: the dataset's own test split, recordings :data:`INDICES` (0–4) of every digit and
speaker: 300 files. Part ``dev``: the speakers :data:`DEV_SPEAKERS`, chosen by a rule fixed
before any score was seen (the alphabetically first speaker of each accent that has two
speakers in FSDD, USA/neutral and German, so that each dev accent keeps a speaker in test);
``test``: the other four.

Labels (``label_source`` :data:`analysis.speech_set.FSDD_WORDS`), for each file:

* the word's span is the file's, less any silent ends found by a fixed energy rule: 10 ms
  frames (non-overlapping from the first sample; a shorter last frame counts as one), RMS level
  in dB; the word runs from the start of the first to the end of the last frame whose level is
  within :data:`TOP_DB` dB of the file's loudest frame; the rest is ``sil``;
* inside the span, the phones and their relative durations are espeak-ng's speaking the digit
  word alone (``tools/espeak_word_phones.py``, as for the GRID part), scaled into the span;
* times are rounded to 0.1 ms (:func:`face_model.forced_align.tidy_segments`).

Written: ``fsdd/<file>.wav`` (unchanged copies), ``fsdd/<file>.csv``, ``fsdd/NOTICE.md``,
``fsdd/SHA256SUMS`` and the manifest's ``fsdd-*`` rows (replaced; the other rows are kept).
``--check`` writes nothing: it regenerates every file in memory (from ``--source`` when that
folder exists, else from the shipped copies, whose bytes ``SHA256SUMS`` then checks) and exits 1
naming each that differs. ``--measure`` prints the energy rule's effect and the part's size.
"""
from __future__ import annotations

import argparse
import csv
import hashlib
import io
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

REPO = Path(__file__).resolve().parents[1]
for _p in (REPO, REPO / "tools"):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

from analysis.speech_set import (FSDD_WORDS, MANIFEST, SET_DIR, load_speech_set,  # noqa: E402
                                 write_labels)
from espeak_word_phones import (file_differences, scale_into, word_phones,  # noqa: E402
                                write_or_check)
from face_model.corpus import PhoneSegment  # noqa: E402
from face_model.forced_align import tidy_segments  # noqa: E402
from groundwork.audio import read_wav  # noqa: E402
from groundwork.errors import CorpusError, ParameterError  # noqa: E402

SOURCE = REPO.parent / "shared" / "fsdd"
SUBDIR = "fsdd"
SPEAKERS = ("george", "jackson", "lucas", "nicolas", "theo", "yweweler")
ACCENTS = {"george": "Greek", "jackson": "USA/neutral", "lucas": "German",
           "nicolas": "Belgian French", "theo": "USA/neutral", "yweweler": "German"}
DEV_SPEAKERS = ("jackson", "lucas")  # first (sorted) of each accent with two speakers
DIGITS = ("zero", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine")
INDICES = range(5)  # the dataset's own test split
SAMPLE_RATE = 8000
FRAME_S = 0.010
TOP_DB = 40.0  # a frame is speech when within this of the file's loudest frame
LICENCE = "Free Spoken Digit Dataset (FSDD) contributors, CC BY-SA 4.0 (fsdd/NOTICE.md)"
NOTICE = """# Free Spoken Digit Dataset (FSDD): a subset, with derived phone labels

The `.wav` files here are **unchanged copies** of 300 recordings of the Free Spoken Digit Dataset
(its own test split: recordings 0–4 of every digit 0–9 and each of its six speakers), named as in
the dataset: `{digit}_{speaker}_{index}.wav`, mono, 8 kHz, 16-bit PCM. `SHA256SUMS` lists each
file's SHA-256.

Source: "Free Spoken Digit Dataset" (FSDD) by its contributors, the public repository
Jakobovski/free-spoken-digit-dataset as of 2024-05-02 (commit 26eb9aaf); the dataset is versioned
with git tags and a Zenodo DOI.

Licence: Creative Commons Attribution-ShareAlike 4.0 International (CC BY-SA 4.0),
https://creativecommons.org/licenses/by-sa/4.0/.

The `.csv` phone label files are **derived material** made from these recordings by
`tools/fsdd_speech_labels.py` (the word's span from the file's energy, the phones inside it timed
by espeak-ng speaking the digit word; see `../README.md`), and are shared under the same licence,
CC BY-SA 4.0.
"""


def subset_names() -> list[str]:
    """The file stems of the subset (``{digit}_{speaker}_{index}``), sorted by speaker, digit,
    index."""
    return [f"{d}_{s}_{i}" for s in SPEAKERS for d in range(len(DIGITS)) for i in INDICES]


def speaker_of(name: str) -> str:
    return name.split("_")[1]


def frame_levels_db(y: np.ndarray, sr: int) -> tuple[np.ndarray, int]:
    """RMS level (dB re full scale) of 10 ms frames of ``y`` (the last may be shorter), and the
    frame length in samples."""
    n = max(1, int(round(FRAME_S * sr)))
    starts = np.arange(0, len(y), n)
    rms = np.array([np.sqrt(np.mean(np.square(y[s:s + n], dtype=np.float64))) for s in starts])
    return 20 * np.log10(np.maximum(rms, 1e-10)), n


def word_span(y: np.ndarray, sr: int) -> tuple[float, float]:
    """``(start_s, end_s)`` of the word: from the first to the last frame within
    :data:`TOP_DB` dB of the loudest (see the module)."""
    db, n = frame_levels_db(y, sr)
    loud = np.flatnonzero(db >= db.max() - TOP_DB)
    return loud[0] * n / sr, min((loud[-1] + 1) * n, len(y)) / sr


def file_labels(y: np.ndarray, sr: int, phones: list, *, source: str) -> list[PhoneSegment]:
    """Contiguous phone segments over the file: ``sil`` outside :func:`word_span`, ``phones``
    (``[(phone, seconds)]``) scaled into it."""
    start, end = word_span(y, sr)
    out = tidy_segments(scale_into(phones, start, end), len(y) / sr)
    if sum(s.phone != "sil" for s in out) != len(phones):
        raise CorpusError(f"{source}: a phone shorter than 0.1 ms after scaling")
    return out


def _read(path: Path) -> np.ndarray:
    y, sr = read_wav(path)
    if sr != SAMPLE_RATE:
        raise CorpusError(f"{path}: sample rate {sr} Hz; FSDD recordings are {SAMPLE_RATE} Hz")
    return y


def _csv_bytes(segs) -> bytes:
    with tempfile.TemporaryDirectory() as tmp:  # write_labels: the set's one writer
        return write_labels(Path(tmp) / "x.csv", segs).read_bytes()


def manifest_rows(names) -> list[dict]:
    """The manifest rows of the FSDD files."""
    return [{"id": f"fsdd_{n}", "wav": f"{SUBDIR}/{n}.wav", "labels": f"{SUBDIR}/{n}.csv",
             "speaker": f"fsdd-{speaker_of(n)}", "label_source": FSDD_WORDS,
             "label_origin": "", "part": "dev" if speaker_of(n) in DEV_SPEAKERS else "test",
             "transcript": DIGITS[int(n.split("_")[0])], "licence": LICENCE} for n in names]


def _manifest_bytes(set_dir: Path, rows_new: list[dict]) -> bytes:
    with open(set_dir / MANIFEST, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        columns = reader.fieldnames
        rows = list(reader)
    ours = [i for i, r in enumerate(rows) if r["speaker"].startswith("fsdd-")]
    at = ours[0] if ours else len(rows)  # in place of the old rows, else at the end
    rows = rows[:at] + rows_new + [r for r in rows[at:] if not r["speaker"].startswith("fsdd-")]
    buf = io.StringIO()
    w = csv.DictWriter(buf, columns, lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue().encode("utf-8")


def _audio_dir(set_dir: Path, source) -> Path:
    """Where the audio is read from: ``source``'s recordings, or the shipped copies."""
    if source is None:
        return set_dir / SUBDIR
    rec = Path(source) / "recordings"
    if not rec.is_dir():
        raise ParameterError(f"--source {source}: no recordings/ folder; give the FSDD download "
                             "(recordings/{digit}_{speaker}_{index}.wav)")
    return rec


def build(set_dir=SET_DIR, source=None, *, progress: bool = True) -> dict[str, bytes]:
    """Every file the tool owns, ``{path relative to the set: contents}``, made in memory from
    ``source`` (the FSDD folder) or, when None, from the shipped copies."""
    set_dir = Path(set_dir)
    audio_dir = _audio_dir(set_dir, source)
    names = subset_names()
    phones = word_phones(DIGITS)
    files, sums = {}, []
    for name in tqdm(names, desc="fsdd labels", unit="file", disable=not progress):
        wav = audio_dir / f"{name}.wav"
        if not wav.is_file():
            raise CorpusError(f"{wav}: FSDD recording not found")
        data = wav.read_bytes()
        files[f"{SUBDIR}/{name}.wav"] = data
        sums.append(f"{hashlib.sha256(data).hexdigest()}  {name}.wav\n")
        segs = file_labels(_read(wav), SAMPLE_RATE, phones[DIGITS[int(name.split('_')[0])]],
                           source=str(wav))
        files[f"{SUBDIR}/{name}.csv"] = _csv_bytes(segs)
    files[f"{SUBDIR}/SHA256SUMS"] = "".join(sums).encode("utf-8")
    files[f"{SUBDIR}/NOTICE.md"] = NOTICE.encode("utf-8")
    files[MANIFEST] = _manifest_bytes(set_dir, manifest_rows(names))
    return files


def differences(set_dir=SET_DIR, files=None) -> list[str]:
    """The files (relative to the set) that differ from ``files`` (default: :func:`build` from
    the shipped copies), and any file in ``fsdd/`` the tool would not write."""
    files = build(set_dir, progress=False) if files is None else files
    return file_differences(set_dir, SUBDIR, files)


def measure(set_dir=SET_DIR) -> dict:
    """The energy rule's effect on the shipped files (silent ends found), the part's size per
    part (speakers, recordings, seconds, bytes), and how long :func:`load_speech_set` takes to
    load the FSDD part and the whole set (wall clock, this machine)."""
    set_dir = Path(set_dir)
    lead, trail, dur = [], [], []
    for name in subset_names():
        y = _read(set_dir / SUBDIR / f"{name}.wav")
        s, e = word_span(y, SAMPLE_RATE)
        lead.append(s)
        trail.append(len(y) / SAMPLE_RATE - e)
        dur.append(len(y) / SAMPLE_RATE)
    lead, trail = np.array(lead), np.array(trail)
    parts = {}
    for row in manifest_rows(subset_names()):
        p = parts.setdefault(row["part"], {"speakers": set(), "recordings": 0, "bytes": 0})
        p["speakers"].add(row["speaker"])
        p["recordings"] += 1
        p["bytes"] += (set_dir / row["wav"]).stat().st_size
    seconds = dict(zip(subset_names(), dur))
    per_speaker = {s: float(sum(v for k, v in seconds.items() if speaker_of(k) == s))
                   for s in SPEAKERS}
    for row in manifest_rows(subset_names()):
        parts[row["part"]].setdefault("seconds", 0.0)
        parts[row["part"]]["seconds"] += seconds[row["id"][5:]]
    fsdd_ids = [r["id"] for r in manifest_rows(subset_names())]
    t0 = time.perf_counter()
    load_speech_set(set_dir, ids=fsdd_ids)
    t1 = time.perf_counter()
    whole = load_speech_set(set_dir)
    t2 = time.perf_counter()
    return {"files": len(dur), "seconds": float(sum(dur)),
            "lead_trimmed": int((lead > 0).sum()), "trail_trimmed": int((trail > 0).sum()),
            "lead_ms": (1000 * float(np.median(lead[lead > 0])) if (lead > 0).any() else 0.0,
                        1000 * float(lead.max())),
            "trail_ms": (1000 * float(np.median(trail[trail > 0])) if (trail > 0).any() else 0.0,
                         1000 * float(trail.max())),
            "sil_share": float((lead.sum() + trail.sum()) / sum(dur)),
            "parts": {k: {**v, "speakers": sorted(v["speakers"])} for k, v in parts.items()},
            "speaker_seconds": per_speaker,
            "load_fsdd_s": t1 - t0, "load_all_s": t2 - t1, "all_items": len(whole),
            "all_seconds": float(sum(it.duration_s for it in whole)),
            "set_parts": {part: {"speakers": len({it.speaker for it in its}),
                                 "recordings": len(its),
                                 "seconds": float(sum(it.duration_s for it in its)),
                                 "independent": sum(it.independent for it in its),
                                 "independent_s": float(sum(it.duration_s for it in its
                                                            if it.independent))}
                          for part in ("dev", "test")
                          for its in [[it for it in whole if it.part == part]]}}


def print_measure(m: dict, out=sys.stdout) -> None:
    print(f"{m['files']} files, {m['seconds']:.1f} s; energy rule (10 ms frames, {TOP_DB:g} dB "
          f"below the loudest): leading silence found in {m['lead_trimmed']} files (median "
          f"{m['lead_ms'][0]:.0f} ms of those, max {m['lead_ms'][1]:.0f} ms), trailing in "
          f"{m['trail_trimmed']} (median {m['trail_ms'][0]:.0f} ms, max "
          f"{m['trail_ms'][1]:.0f} ms); {m['sil_share']:.1%} of the audio labelled sil by it",
          file=out)
    for name, p in sorted(m["parts"].items()):
        print(f"part {name}: {len(p['speakers'])} speakers ({', '.join(p['speakers'])}), "
              f"{p['recordings']} recordings, {p['seconds']:.1f} s, {p['bytes']:,} bytes",
              file=out)
    print("seconds per speaker: " + ", ".join(f"fsdd-{s} {v:.1f}"
                                              for s, v in m["speaker_seconds"].items()), file=out)
    for name, p in m["set_parts"].items():
        print(f"whole set, part {name}: {p['speakers']} speakers, {p['recordings']} recordings, "
              f"{p['seconds']:.1f} s; independently labelled {p['independent']} recordings, "
              f"{p['independent_s']:.1f} s", file=out)
    print(f"load_speech_set: FSDD part {m['load_fsdd_s']:.2f} s; whole set ({m['all_items']} "
          f"recordings, {m['all_seconds']:.1f} s) {m['load_all_s']:.2f} s", file=out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--set-dir", type=Path, default=SET_DIR)
    p.add_argument("--source", type=Path, default=SOURCE,
                   help="the FSDD download (default: ../shared/fsdd beside the repository)")
    p.add_argument("--check", action="store_true", help="compare with the shipped files")
    p.add_argument("--measure", action="store_true", help="print the energy rule's effect, "
                   "the part's size and the set's loading time")
    args = p.parse_args(argv)
    if args.measure:
        print_measure(measure(args.set_dir))
        return 0
    source = args.source
    if args.check and not (source / "recordings").is_dir():
        print(f"{source}: no FSDD download; checking against the shipped copies",
              file=sys.stderr)
        source = None
    files = build(args.set_dir, source)
    return write_or_check(args.set_dir, SUBDIR, files, check=args.check)


if __name__ == "__main__":
    sys.exit(main())
