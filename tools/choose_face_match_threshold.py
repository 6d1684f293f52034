"""Re-run the measurement behind ``MAX_FACE_MISFIT`` of ``face_model/face_match.py``: the misfit
of a clip's neutral face to a speaker's above which ``evaluate-face`` refuses to score the clips as
that speaker.

    python tools/choose_face_match_threshold.py [--real DIR] [--speakers N] [--sentences N]
                                                [--seed S] [--json] [--check]

The faces: the real corpus ``DIR`` (default: the built-in GRID s1 corpus,
``face_model/real_faces/grid-s1``) and a synthetic corpus made here in a temporary folder by the
generator's defaults (``--speakers`` speakers, default 8, × ``--sentences`` neutral sentences,
default 8, seed ``--seed``, default the run seed). Each speaker's neutral utterances, in corpus
order, are split: the even positions give the speaker's **reference** neutral face (the median of
their aligned first frames, as :func:`face_model.alignment.speaker_neutrals` gives a model's), the
odd positions are the **probes**, one clip each — the hardest case of ``evaluate-face``: a
single clip's neutral face (:func:`face_model.face_match.first_frame_neutral`). A misfit is
:func:`face_model.face_match.face_misfit` (percent of the face's size) of a probe against a
reference. The populations:

* ``same, real`` / ``same, synthetic``: each probe against its own speaker's reference;
* ``other source, real as synthetic``: each real probe against every synthetic speaker's
  reference (the issue's case: a real face scored as a synthetic training speaker), and
  ``other source, synthetic as real``: each synthetic probe against the real speaker's;
* ``other synthetic speaker``: each synthetic probe against every other synthetic speaker's;
* ``real, x 0.9 wide`` / ``real, x 1.1 wide``: each real probe stretched horizontally about its
  first frame's centre (before alignment) against the real speaker's own reference — a proxy
  for another person's proportions.

**The rule**: the pick is the midpoint between the largest ``same`` misfit and the smallest
``other source`` misfit, rounded to 0.1 %. The last three populations are printed, with the
share the pick refuses, but not used to choose: they overlap the real speaker's own clips, so no
threshold refuses them without refusing some of the speaker's own clips. The tool also prints
what speech moves on each region (why the lips are left out of the fit) and, for the markers off
the lips (the check's), all markers and the upper face alone, the largest ``same`` misfit, the
smallest ``other source`` one and the smallest stretched one. ``--check`` exits 1 with one line
when ``MAX_FACE_MISFIT`` is not the pick. Most of its time goes on the synthesis.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from data_synth.config import SynthConfig  # noqa: E402
from data_synth.generate import synthesize_corpus  # noqa: E402
from face_model import face_match  # noqa: E402
from face_model.alignment import align_markers  # noqa: E402
from face_model.corpus import load_corpus  # noqa: E402
from face_model.layout import REGIONS  # noqa: E402
from groundwork.errors import ParameterError  # noqa: E402
from talkingface.config import Config  # noqa: E402

BUILTIN = REPO / "face_model" / "real_faces" / "grid-s1"
STRETCHES = (0.9, 1.1)  # horizontal factors of the stretched real probes
SAME = ("same, real", "same, synthetic")
OTHER = ("other source, real as synthetic", "other source, synthetic as real")
SHOWN = ("other synthetic speaker", *(f"real, x {f} wide" for f in STRETCHES))
MARKER_SETS = {"off the lips (the check's)": face_match.FIT_MARKERS,
               "all 79": tuple(range(79)),
               "upper face (forehead, glasses)": (*REGIONS["forehead"], *REGIONS["glasses"])}


@dataclasses.dataclass(frozen=True)
class Speaker:
    """One speaker's reference neutral face (79, 2) and its probes' first frames before
    alignment (each (1, 79, 2), pixels)."""

    name: str
    reference: np.ndarray
    probes: tuple


def speakers_of(corpus) -> list[Speaker]:
    """Each speaker's reference and probes (module text), from its neutral utterances."""
    by: dict = {}
    for u in corpus.utterances:
        if u.expression == "neutral":
            by.setdefault(u.speaker, []).append(u.markers[:1].astype(np.float64))
    out = []
    for name, firsts in by.items():
        if len(firsts) < 2:
            raise ParameterError(f"speaker {name!r}: {len(firsts)} neutral utterance; the split "
                                 "into reference and probes needs at least 2")
        ref = face_match.first_frame_neutral([align_markers(f) for f in firsts[0::2]])
        out.append(Speaker(name, ref, tuple(firsts[1::2])))
    return out


def stretched(first: np.ndarray, factor: float) -> np.ndarray:
    """``first`` (1, 79, 2) scaled horizontally by ``factor`` about its centre."""
    c = first[0].mean(0)
    return (first - c) * np.array([factor, 1.0]) + c


def populations(real: list[Speaker], synth: list[Speaker], markers=face_match.FIT_MARKERS
                ) -> dict[str, np.ndarray]:
    """Misfits (percent) of each population of the module text."""
    def misfit(first, ref):
        return face_match.face_misfit(align_markers(first)[0], ref, markers=markers)

    def pairs(probes_of, refs_of, keep):
        return np.array([misfit(p, b.reference) for a in probes_of for b in refs_of
                         if keep(a, b) for p in a.probes])

    out = {"same, real": pairs(real, real, lambda a, b: a is b),
           "same, synthetic": pairs(synth, synth, lambda a, b: a is b),
           "other source, real as synthetic": pairs(real, synth, lambda a, b: True),
           "other source, synthetic as real": pairs(synth, real, lambda a, b: True),
           "other synthetic speaker": pairs(synth, synth, lambda a, b: a is not b)}
    for f in STRETCHES:
        out[f"real, x {f} wide"] = np.array([misfit(stretched(p, f), s.reference)
                                             for s in real for p in s.probes])
    return out


def pick(pops: dict[str, np.ndarray]) -> float:
    """The midpoint between the largest ``same`` misfit and the smallest ``other source`` one,
    rounded to 0.1 % (module text)."""
    same = max(float(pops[k].max()) for k in SAME)
    other = min(float(pops[k].min()) for k in OTHER)
    if other <= same:
        raise ParameterError(f"the smallest other-source misfit ({other:.2f} %) is not above "
                             f"the largest same-speaker one ({same:.2f} %): no threshold "
                             "separates them")
    return round((same + other) / 2, 1)


def region_motion(real: list[Speaker], corpus) -> dict[str, float]:
    """RMS distance of each region's aligned markers from the speaker's reference over all
    frames of the real corpus, percent of the face's size."""
    ref = {s.name: s.reference for s in real}
    dev = np.concatenate([align_markers(u.markers) - ref[u.speaker][None]
                          for u in corpus.utterances if u.speaker in ref])
    size = {k: face_match.face_size(v) for k, v in ref.items()}
    scale = 100.0 / float(np.mean(list(size.values())))
    return {r: float(np.sqrt((dev[:, list(idx)] ** 2).sum(2).mean()) * scale)
            for r, idx in REGIONS.items()}


def table(pops: dict[str, np.ndarray], threshold: float) -> list[dict]:
    """One row per population: its use, the number of pairs, the quantiles and the share of
    pairs the threshold refuses."""
    rows = []
    for name, v in pops.items():
        use = "same" if name in SAME else "other" if name in OTHER else "shown"
        rows.append({"population": name, "used as": use, "pairs": int(len(v)),
                     "min": float(v.min()), "median": float(np.median(v)),
                     "p99": float(np.percentile(v, 99)), "max": float(v.max()),
                     "refused %": float(100.0 * np.mean(v > threshold))})
    return rows


def measure(real_dir, *, n_speakers: int, n_sentences: int, seed: int) -> dict:
    """Everything the command prints (module text)."""
    real_corpus = load_corpus(real_dir)
    real = speakers_of(real_corpus)
    cfg = dataclasses.replace(SynthConfig(), speakers=n_speakers, n_sentences=n_sentences,
                              expressions=("neutral",), workers=2)
    with tempfile.TemporaryDirectory(prefix="face-match-") as tmp:
        synth = speakers_of(load_corpus(synthesize_corpus(Path(tmp) / "corpus", cfg, seed,
                                                          progress=False)))
    pops = populations(real, synth)
    threshold = pick(pops)
    sets = {}
    for name, markers in MARKER_SETS.items():
        p = populations(real, synth, markers)
        sets[name] = {"largest same": max(float(p[k].max()) for k in SAME),
                      "smallest other source": min(float(p[k].min()) for k in OTHER),
                      "smallest stretched": min(float(p[k].min()) for k in SHOWN[1:])}
    return {"real": str(real_dir), "synthetic": {"speakers": n_speakers,
                                                  "sentences": n_sentences, "seed": seed},
            "region_motion": region_motion(real, real_corpus), "marker_sets": sets,
            "rows": table(pops, threshold), "pick": threshold}


def render(res: dict) -> str:
    """The printed tables."""
    lines = [f"real: {res['real']}; synthetic: {res['synthetic']['speakers']} speakers x "
             f"{res['synthetic']['sentences']} neutral sentences, seed {res['synthetic']['seed']}",
             "speech motion on the real corpus (RMS from the neutral face, % of the face's "
             "size): " + ", ".join(f"{k} {v:.2f}" for k, v in res["region_motion"].items()),
             "", f"{'markers fitted':34s} {'largest same':>13s} {'smallest other source':>22s} "
             f"{'smallest stretched':>19s}"]
    for name, s in res["marker_sets"].items():
        lines.append(f"{name:34s} {s['largest same']:13.2f} {s['smallest other source']:22.2f} "
                     f"{s['smallest stretched']:19.2f}")
    lines += ["", "misfit, % of the face's size (markers off the lips):",
              f"{'population':34s} {'used as':7s} {'pairs':>6s} {'min':>6s} {'median':>7s} "
              f"{'p99':>6s} {'max':>6s} {'refused %':>10s}"]
    for r in res["rows"]:
        lines.append(f"{r['population']:34s} {r['used as']:7s} {r['pairs']:6d} {r['min']:6.2f} "
                     f"{r['median']:7.2f} {r['p99']:6.2f} {r['max']:6.2f} {r['refused %']:10.1f}")
    lines.append(f"pick (midpoint of the largest same and the smallest other source, 0.1 %): "
                 f"{res['pick']:.1f} %")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--real", type=Path, default=BUILTIN, help="a real speaker's corpus folder")
    ap.add_argument("--speakers", type=int, default=8, help="synthetic speakers (at least 2)")
    ap.add_argument("--sentences", type=int, default=8, help="neutral sentences per synthetic "
                    "speaker (at least 2)")
    ap.add_argument("--seed", type=int, default=Config().seed)
    ap.add_argument("--json", action="store_true", help="print the results as JSON")
    ap.add_argument("--check", action="store_true", help="exit 1 when MAX_FACE_MISFIT is not "
                    "the pick")
    args = ap.parse_args(argv)
    if args.speakers < 2 or args.sentences < 2:
        print(f"error: --speakers {args.speakers} --sentences {args.sentences}; allowed: 2 or "
              "more each", file=sys.stderr)
        return 2
    res = measure(args.real, n_speakers=args.speakers, n_sentences=args.sentences,
                  seed=args.seed)
    print(json.dumps(res, indent=1) if args.json else render(res))
    if args.check and res["pick"] != face_match.MAX_FACE_MISFIT:
        print(f"MAX_FACE_MISFIT is {face_match.MAX_FACE_MISFIT} in face_model/face_match.py; "
              f"the pick is {res['pick']}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
