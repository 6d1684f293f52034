"""The lip-sync tools users already use (:mod:`mapping.peers`) scored on the real-speech set
beside the models, with the same metrics (DESIGN.md, "Evaluation on real data": peers on the
same data).

Each peer's track (:func:`mapping.peers.peer_track`) gives a mouth opening in its own units and,
for all but the loudness envelope, a viseme per frame. Scored here: viseme frame accuracy
against the labelled phones' visemes; /p b m/ closure as the closed viseme ``m`` shown in a
frame overlapping the segment (:func:`analysis.speech_scores.viseme_contact`: a tool that gives
no pixels cannot be held to a pixel threshold); and the speech-frame r of its opening with the
generator's reference articulation (the same r the models get: clips centred and scaled). Each
beside its chance baseline (its own track circularly shifted).

Words given to the transcript mode: a GRID recording's own ``.align`` word times (its
``label_origin``, :func:`face_model.transcripts.read_align`); an FSDD recording is one word
spanning the file; any other recording, the transcript only.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from analysis.speech_eval import NATIVE, rate_audio, reference_opening
from analysis.speech_scores import (chance_scores, correlation, label_frames, phone_frames,
                                    speech_r_terms, viseme_contact, viseme_index)
from analysis.speech_set import FSDD_WORDS
from face_model.phones import BILABIALS, PHONE_INDEX
from face_model.transcripts import read_align
from mapping.peers import PEERS, peer_track


def peer_words(item, set_dir) -> list | None:
    """The word times the transcript mode gets for ``item`` (see the module docstring)."""
    origin = (item.label_origin or "").strip()
    if origin.endswith(".align"):
        return list(read_align(Path(set_dir) / origin).words)
    if item.label_source == FSDD_WORDS:
        return [(0.0, item.duration_s, item.transcript)]
    return None


def scored_peers() -> tuple:
    """The peers of :data:`mapping.peers.PEERS` (all of them: the loudness envelope has no
    visemes but its opening still has an r)."""
    return tuple(PEERS)


def peer_scores(items, set_dir, synth, seed: int, *, seen=frozenset(), fps: int = 30,
                peers=None, stream_key: str = "viseme_acc_stream_100ms",
                progress=None) -> list:
    """Per-file rows (the columns :mod:`analysis.speech_pooling` pools) of each peer on
    ``items`` at their native rate; ``synth`` and ``seed`` draw the reference articulation
    (those of the model the peers are compared with). A peer's streaming column is empty: the
    tools are scored as users run them, on whole files."""
    rows = []
    for peer in peers or scored_peers():
        if progress:
            progress(f"the peer {peer} on {len(items)} recordings")
        for it in items:
            y, sr, note = rate_audio(it, NATIVE)
            n = label_frames(len(y), sr, fps)
            track = peer_track(peer, y, sr, n_frames=n, fps=fps,
                               words=peer_words(it, set_dir), transcript=it.transcript)
            true = phone_frames(it.phones, np.arange(n) / fps)
            ref = reference_opening(it.phones, n, fps, synth, seed)
            opening = np.asarray(track.opening, np.float64)
            terms, n_speech = speech_r_terms(opening, ref, true)
            sel = true != PHONE_INDEX["sil"]
            row = {"model": peer, "id": it.id, "speaker": it.speaker,
                   "split": "seen" if it.speaker in seen else "unseen", "part": it.part,
                   "kind": it.kind, "labels": "independent" if it.independent else "aligned",
                   "input_rate": NATIVE, "rate_note": note, "seconds": round(len(y) / sr, 3),
                   "frames": n, "speech_frames": n_speech, stream_key: float("nan"),
                   "r_reference": correlation(opening[sel], ref[sel]), "r_terms": terms}
            if track.visemes is not None:
                vis = np.asarray(track.visemes)
                met = viseme_contact(vis, fps, it.phones, BILABIALS)
                chance = chance_scores(true, fps, it.phones, visemes=vis)
                hits = int(np.sum(vis == viseme_index(true)))
                row.update(viseme_hits=hits, viseme_acc=hits / n,
                           bilabial_segments=len(met), bilabial_closed=int(met.sum()),
                           bilabial_closed_frac=float(met.mean()) if len(met) else np.nan,
                           chance_viseme_hits=chance.viseme_hits / chance.n_shifts,
                           chance_closed=chance.closed / chance.n_shifts)
            else:
                row.update(viseme_hits=np.nan, bilabial_closed=np.nan,
                           bilabial_segments=sum(s.phone in BILABIALS for s in it.phones))
            shifted = chance_scores(true, fps, it.phones, opening=opening, reference=ref,
                                    threshold=-np.inf)
            row["chance_r_terms"] = shifted.r_terms / shifted.n_shifts
            rows.append(row)
    return rows
