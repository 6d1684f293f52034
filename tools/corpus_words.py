"""Add the words' times (``words/<utt_id>.csv``) to a corpus made from GRID video, from the
``.align`` files of its clips, without running the landmark detector again.

    python tools/corpus_words.py CORPUS --align-dir DIR [--check]

Each utterance of ``CORPUS``'s manifest takes ``DIR/<utt_id>.align`` (GRID's word alignment,
:func:`face_model.transcripts.read_align`): its words, silences ``sil``/``sp`` left out, must be
the manifest's ``text`` word by word (else nothing is written and the first clip that differs is
named); they are written as ``words/<utt_id>.csv`` (:func:`face_model.corpus.write_words`, what
``talkingface corpus from-video`` writes for a clip with an ``.align``), ``corpus.json`` gains
its ``words`` entry (how many utterances, from where, by which command), and the whole folder
must then pass the corpus reader. ``NOTICE.md``, when there is one, is left to the caller.

``--check`` writes nothing: it exits 1, naming the first difference, unless every utterance's
words file is there and equal to what the ``.align`` gives (the shipped GRID s1 corpus:
``python tools/corpus_words.py face_model/real_faces/grid-s1 --align-dir ../shared/grid-s1/align
--check``).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from face_model.corpus import (load_corpus, read_manifest, words_path,  # noqa: E402
                               write_words)
from face_model.transcripts import read_align  # noqa: E402
from face_model.video_import import words_info  # noqa: E402
from groundwork.atomic import atomic_file  # noqa: E402
from groundwork.errors import TalkingFaceError  # noqa: E402


def align_words(corpus: Path, align_dir: Path) -> dict:
    """``{utt_id: ((start_s, end_s, word), ...)}`` of every utterance of ``corpus`` from its
    ``.align`` in ``align_dir``, each checked against the manifest's text.

    Raises
    ------
    TalkingFaceError
        A missing or malformed ``.align``, or one whose words are not the utterance's text.
    """
    out = {}
    for row in read_manifest(corpus / "manifest.csv"):
        t = read_align(align_dir / f"{row['utt_id']}.align")
        if t.text.lower().split() != row["text"].lower().split():
            raise TalkingFaceError(f"{t.source}: words {t.text!r}, but the manifest of {corpus} "
                                   f"has {row['text']!r} for {row['utt_id']}; allowed: the "
                                   "alignment of the utterance's own sentence")
        out[row["utt_id"]] = t.words
    return out


def check(corpus: Path, align_dir: Path) -> list[str]:
    """The differences between ``corpus``'s words files and its ``.align`` files (empty: none)."""
    problems = []
    with tempfile.TemporaryDirectory() as tmp:
        for utt, words in align_words(corpus, align_dir).items():
            path = words_path(corpus, utt)
            if not path.is_file():
                problems.append(f"{path}: missing")
            elif path.read_bytes() != (Path(tmp) / write_words(tmp, utt, words)).read_bytes():
                problems.append(f"{path}: differs from {align_dir / (utt + '.align')}")
    info = json.loads((corpus / "corpus.json").read_text(encoding="utf-8"))
    n = len(read_manifest(corpus / "manifest.csv"))
    if (info.get("words") or {}).get("utterances") != n:
        problems.append(f"{corpus / 'corpus.json'}: its words entry does not say {n} utterances")
    return problems


def add_words(corpus: Path, align_dir: Path, command: str) -> int:
    """Write the words files and ``corpus.json``'s ``words`` entry; return how many files."""
    words = align_words(corpus, align_dir)
    for utt, w in words.items():
        write_words(corpus, utt, w)
    info_path = corpus / "corpus.json"
    info = json.loads(info_path.read_text(encoding="utf-8"))
    info["words"] = {**words_info(len(words), "the clips' .align word times"),
                     "added_by": command}
    with atomic_file(info_path) as tmp:
        tmp.write_text(json.dumps(info, indent=1) + "\n")
    load_corpus(corpus)  # every words file read back and checked against its text
    return len(words)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("corpus", type=Path)
    p.add_argument("--align-dir", type=Path, required=True,
                   help="the folder of the clips' .align files (GRID's align/)")
    p.add_argument("--check", action="store_true", help="write nothing; exit 1 unless the "
                   "words files equal what the .align files give")
    args = p.parse_args(argv)
    try:
        if args.check:
            problems = check(args.corpus, args.align_dir)
            for line in problems:
                print(line)
            print(f"{args.corpus}: words files {'differ' if problems else 'match'} "
                  f"({args.align_dir})")
            return 1 if problems else 0
        command = (f"python tools/corpus_words.py {args.corpus} --align-dir "
                   f"{args.align_dir}")
        n = add_words(args.corpus, args.align_dir, command)
    except TalkingFaceError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.corpus}: {n} words files (words/<utt_id>.csv) from {args.align_dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
