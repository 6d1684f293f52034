"""Regenerate the phone labels of the real-speech evaluation set (``analysis/real_speech/``).

    python tools/align_real_speech.py [--set-dir DIR] [--check] [ID ...]

For every recording of the manifest (or the ids given) the phone file ``labels`` is made from
its ``label_source``:

* ``hts``: the HTS full-context labels shipped beside it (``label_origin``), festival symbols
  mapped to the 44 classes (``pau`` → ``sil``; ``ax`` kept);
* ``textgrid``: its own TextGrid's ``phone`` tier (ARPAbet with stress; ``PT`` split in two);
* ``pocketsphinx-5.1.1 forced alignment``: the transcript aligned to the audio by
  :func:`face_model.forced_align.align` (pocketsphinx's en-US acoustic model, shipped in the
  wheel; nothing is downloaded): words first, then phones in 10 ms frames; silences and noise
  are ``sil``; the ends are padded with silence to the length of the audio.

The GRID and FSDD recordings are left to their own tools (``tools/grid_speech_labels.py``,
``tools/fsdd_speech_labels.py``). ``--check`` writes nothing and exits 1 when a regenerated
file differs from the shipped one.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from analysis.speech_set import (ALIGNED, FSDD_WORDS, GRID_WORDS, SET_DIR,  # noqa: E402
                                 hts_segments, read_manifest, textgrid_segments, write_labels)
from face_model.forced_align import align, aligner, to_pcm16  # noqa: E402
from groundwork.audio import read_wav  # noqa: E402


def labels_for(row: dict, set_dir: Path, dec=None) -> list:
    """The phone segments of one manifest row, from its label source."""
    y, sr = read_wav(set_dir / row["wav"])
    duration = len(y) / sr
    if row["label_source"] == "hts":
        return hts_segments(set_dir / row["label_origin"], duration)
    if row["label_source"] == "textgrid":
        return textgrid_segments(set_dir / row["label_origin"], duration)
    assert row["label_source"] == ALIGNED
    return align(dec or aligner(), to_pcm16(y, sr), row["transcript"],
                 source=str(set_dir / row["wav"]))


def regenerate(set_dir=SET_DIR, ids=None, *, check: bool = False, out=sys.stdout) -> list:
    """Write (or with ``check`` compare) the phone files; returns the ids that differ."""
    set_dir = Path(set_dir)
    # the GRID and FSDD parts have their own tools (tools/grid_speech_labels.py,
    # tools/fsdd_speech_labels.py)
    rows = [r for r in read_manifest(set_dir) if (ids is None or r["id"] in ids)
            and r["label_source"] not in (GRID_WORDS, FSDD_WORDS)]
    dec = aligner() if any(r["label_source"] == ALIGNED for r in rows) else None
    differ = []
    for row in rows:
        segs = labels_for(row, set_dir, dec)
        target = set_dir / row["labels"]
        if check:
            tmp = target.with_name(f".{target.name}.check")
            try:
                same = target.is_file() and (write_labels(tmp, segs).read_bytes()
                                             == target.read_bytes())
            finally:
                tmp.unlink(missing_ok=True)
            if not same:
                differ.append(row["id"])
            print(f"{row['id']}: {'same' if same else 'DIFFERS'}", file=out)
        else:
            write_labels(target, segs)
            print(f"{row['id']}: {len(segs)} segments -> {target}", file=out)
    return differ


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("ids", nargs="*", help="recordings to do (default: all)")
    p.add_argument("--set-dir", type=Path, default=SET_DIR)
    p.add_argument("--check", action="store_true", help="compare with the shipped files")
    args = p.parse_args(argv)
    differ = regenerate(args.set_dir, args.ids or None, check=args.check)
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
