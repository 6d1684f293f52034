"""Whether a set of clips shows a given speaker's face: the shape of their neutral face against
the speaker's neutral face, after a similarity fit.

A model scored on a speaker it was trained on predicts that speaker's neutral face plus the
deformation from the audio (paper Eq. 2), and the lip vertex error is measured against the clips'
markers. Clips of another person scored under that speaker's name give an LVE that measures the
difference of two faces, not the model; :func:`check_face_match` refuses them.

The measure (:func:`face_misfit`): both neutral faces in the aligned frame
(:func:`face_model.alignment.align_markers`), the clips' mapped onto the speaker's by the
least-squares similarity (rotation, isotropic scale, translation) of :data:`FIT_MARKERS`; the misfit
is the RMS distance left over those markers divided by their RMS distance from their centre in the
speaker's face (the face's size), in percent — the same for any image resolution. The markers
are those off the lips (forehead, cheeks, glasses: 49 of the 79): the lips are the markers speech
moves most, and a clip's first frame (the neutral face's estimate, as for the speaker's own:
:func:`face_model.alignment.speaker_neutrals`) may already be in speech. What speech moves on each
region, and the misfits of the markers off the lips against those of all markers and of the upper
face alone, are printed by ``python tools/choose_face_match_threshold.py``.

The threshold :data:`MAX_FACE_MISFIT` is chosen by that command on the built-in corpora (module
text of the tool): the midpoint between the largest misfit of one clip against its own speaker's
neutral face (real: the GRID s1 corpus; synthetic: the generator's speakers) and the smallest of a
face from the other source (a real clip against a synthetic speaker, a synthetic clip against the
real speaker). One clip of the real speaker misfits its own neutral face by as much as the
synthetic speakers misfit each other, so faces that close are not told apart from one clip: the
check catches a face of another kind, not every other person.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from face_model.alignment import similarity_params
from face_model.layout import N_MARKERS, REGIONS
from groundwork.errors import ParameterError

FIT_REGIONS = ("forehead", "cheeks", "glasses")
FIT_MARKERS = tuple(i for r in FIT_REGIONS for i in REGIONS[r])  # the 49 markers off the lips
# Percent of the face's size. Chosen by `python tools/choose_face_match_threshold.py` (the
# midpoint rule of the module text; `--check` fails when this is not its pick).
MAX_FACE_MISFIT = 9.3


def _face(points, name: str) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    if p.shape != (N_MARKERS, 2):
        raise ParameterError(f"{name} must have shape ({N_MARKERS}, 2), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ParameterError(f"{name} holds NaN or inf values")
    return p


def face_size(face, *, markers: Sequence[int] = FIT_MARKERS) -> float:
    """RMS distance of ``markers`` from their centre (pixels).

    Parameters
    ----------
    face : ndarray, shape (79, 2)
        Marker positions, pixels.
    markers : sequence of int
        Marker indices.

    Returns
    -------
    float
        Pixels.
    """
    p = _face(face, "face")[list(markers)]
    return float(np.sqrt(((p - p.mean(0)) ** 2).sum(1).mean()))


def face_misfit(face, reference, *, markers: Sequence[int] = FIT_MARKERS) -> float:
    """How far ``face``'s shape is from ``reference``'s (module text).

    Parameters
    ----------
    face, reference : ndarray, shape (79, 2)
        Neutral faces, pixels (any frame: the similarity removes position, rotation and size).
    markers : sequence of int
        The markers fitted and measured (default :data:`FIT_MARKERS`); at least 3.

    Returns
    -------
    float
        RMS residual of ``markers`` after the least-squares similarity ``face`` → ``reference``,
        in percent of ``reference``'s :func:`face_size`; 0 for the same shape at any position,
        rotation and scale.

    Raises
    ------
    ParameterError
        Faces not (79, 2) or not finite, fewer than 3 markers, a reference of no size.
    """
    f, r = _face(face, "face"), _face(reference, "reference")
    idx = list(markers)
    if len(idx) < 3:
        raise ParameterError(f"markers: {len(idx)} given; a similarity fit needs at least 3")
    size = face_size(r, markers=idx)
    if size <= 1e-9:
        raise ParameterError("reference: its markers all lie at one point; a face's size is "
                             "needed")
    A, t = similarity_params(f[None, idx], r[None, idx])
    fitted = f[idx] @ A[0].T + t[0]
    return float(100.0 * np.sqrt(((fitted - r[idx]) ** 2).sum(1).mean()) / size)


def first_frame_neutral(aligned: Sequence[np.ndarray]) -> np.ndarray:
    """A set of clips' neutral face: the median of their aligned first frames (the estimate
    of :func:`face_model.alignment.speaker_neutrals`).

    Parameters
    ----------
    aligned : sequence of ndarray, each shape (n_frames, 79, 2)
        The clips' aligned markers, pixels.

    Returns
    -------
    ndarray, shape (79, 2)
        Pixels.
    """
    if not len(aligned):
        raise ParameterError("aligned: no clip given; a neutral face needs at least one")
    return np.median(np.stack([np.asarray(a, np.float64)[0] for a in aligned]), axis=0)


def check_face_match(speaker: str, clips: Sequence[str], face, reference, *,
                     threshold: float = MAX_FACE_MISFIT) -> float:
    """Refuse clips whose neutral face does not fit ``speaker``'s.

    Parameters
    ----------
    speaker : str
        The speaker the clips are scored as.
    clips : sequence of str
        The clips' names (the first is named in the message).
    face : ndarray, shape (79, 2)
        The clips' neutral face (:func:`first_frame_neutral`), pixels.
    reference : ndarray, shape (79, 2)
        The speaker's neutral face, pixels.
    threshold : float
        The largest misfit accepted, percent of the face's size (:data:`MAX_FACE_MISFIT`).

    Returns
    -------
    float
        The misfit (:func:`face_misfit`), percent.

    Raises
    ------
    ParameterError
        The misfit is above ``threshold``: one line naming the speaker, the first clip, the
        misfit and the threshold. Also: no clip named, faces not (79, 2) or not finite.
    """
    names = [str(c) for c in clips]
    if not names:
        raise ParameterError(f"clips: none named for speaker {speaker!r}; at least one needed")
    misfit = face_misfit(face, reference)
    if misfit > threshold:
        if len(names) == 1:
            which, verb, their = f"clip {names[0]}", "shows", "its"
        else:
            which, verb, their = f"clips {names[0]} (and {len(names) - 1} more)", "show", "their"
        raise ParameterError(
            f"{which} scored as speaker {speaker!r} {verb} another face: {their} neutral face "
            f"misfits the speaker's by {misfit:.1f} % of the face's size (RMS after a similarity "
            f"fit on the markers off the lips; at most {threshold:.1f} % allowed, "
            "tools/choose_face_match_threshold.py); name the clips' own speaker")
    return misfit
