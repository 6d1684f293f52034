"""Make the built-in real corpus (``face_model/real_faces/grid-s1/``) from GRID speaker s1's videos.

    python tools/build_real_corpus.py GRID_S1_DIR [--out face_model/real_faces/grid-s1]

``GRID_S1_DIR`` holds ``video/<id>.mpg`` and ``align/<id>.align`` (the layout of the GRID
release, e.g. ``../shared/grid-s1``). The 200 clips listed in ``face_model/real_faces/grid-s1.ids``
(every other clip of the 400 in sorted order) go through ``talkingface corpus from-video``
(:func:`face_model.video_import.corpus_from_video`) with FLAC audio; the clips it refuses are
listed in the corpus's ``refused.csv``. The attribution is kept in the corpus's ``NOTICE.md`` and
``corpus.json``.
"""
from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from face_model.video_corpus import FromVideoSettings  # noqa: E402
from face_model.video_import import corpus_from_video  # noqa: E402

IDS = REPO / "face_model" / "real_faces" / "grid-s1.ids"
LICENCE = ("GRID audio-visual corpus, speaker s1: M. Cooke, J. Barker, S. Cunningham, X. Shao "
           "(2006), 'An audio-visual corpus for speech perception and automatic speech "
           "recognition', JASA 120(5):2421-2424; Zenodo record 3625687; Creative Commons "
           "Attribution 4.0 (CC BY 4.0). Landmarks, markers, phones and resampled audio derived "
           "by talkingface.")
NOTICE = """# GRID speaker s1: the built-in real corpus

Markers (MediaPipe Face Mesh landmarks → the 79-marker layout), phones (forced alignment) and
audio (resampled to 22,050 Hz, FLAC) of {n} sentences of speaker s1 of the GRID corpus, made by
`tools/build_real_corpus.py` (`talkingface corpus from-video`) from the clips listed in
`../grid-s1.ids`. Clips the import refused are in `refused.csv`.

Source: the GRID corpus, M. Cooke, J. Barker, S. Cunningham, X. Shao (2006), "An audio-visual
corpus for speech perception and automatic speech recognition", *JASA* 120(5):2421–2424;
released on Zenodo (record 3625687) under the Creative Commons Attribution 4.0 licence
(https://creativecommons.org/licenses/by/4.0/). These files are derived from it (landmarks
tracked, audio resampled); the changes are described above.
"""


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("grid", type=Path)
    p.add_argument("--out", type=Path, default=REPO / "face_model" / "real_faces" / "grid-s1")
    p.add_argument("--workers", type=int, default=2)
    args = p.parse_args(argv)
    ids = IDS.read_text().split()
    with tempfile.TemporaryDirectory() as tmp:
        video, align = Path(tmp) / "grid-s1" / "video", Path(tmp) / "grid-s1" / "align"
        video.mkdir(parents=True)
        align.mkdir()
        for i in ids:
            (video / f"{i}.mpg").symlink_to((args.grid / "video" / f"{i}.mpg").resolve())
            (align / f"{i}.align").symlink_to((args.grid / "align" / f"{i}.align").resolve())
        settings = FromVideoSettings(speaker="grid-s1", audio_format="flac")
        res = corpus_from_video(video, args.out, settings=settings, workers=args.workers,
                                licence=LICENCE, source="GRID corpus, speaker s1: video/<id>.mpg "
                                "and align/<id>.align of the clips in grid-s1.ids")
    (args.out / "NOTICE.md").write_text(NOTICE.format(n=res["utterances"]))
    print(f"{args.out}: {res['utterances']} utterances, {res['frames']} frames; "
          f"{len(res['refused'])} refused")
    return 0


if __name__ == "__main__":
    sys.exit(main())
