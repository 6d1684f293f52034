"""The 44 phone classes, their visemes and their articulatory targets.

The class set is the 39 ARPAbet phonemes plus ``ax dx el en sil`` (the paper's footnote 2: one
Gaussian mixture and one MLP per class). This one table is shared by the corpus generator (targets
and dominance for coarticulation), the phone-class gate (labels) and the keyframe conversion
(visemes ``i a o f u m``).

Articulatory parameters (all dimensionless, 0 = rest, 1 = the extreme the face model allows):

=============  ===============================================================
``jaw``        jaw opening
``aperture``   lip opening beyond what the jaw gives
``spread``     lip spreading (corners pulled outward)
``protrusion`` lip rounding / protrusion (corners pulled inward, lips pursed)
``upper_raise`` upper-lip raise
``lower_tuck`` lower lip tucked up under the upper teeth (f, v)
``closure``    bilabial closure (p, b, m)
=============  ===============================================================

Dominance ``alpha`` (Cohen & Massaro, 1993) is given per phone for the lip parameters and the jaw:
bilabials and labiodentals dominate the lips, vowels moderately, lingual consonants hardly at all.
"""
from __future__ import annotations

import re

import numpy as np

from groundwork.errors import CorpusError, ParameterError

ARTIC_PARAMS = ("jaw", "aperture", "spread", "protrusion", "upper_raise", "lower_tuck", "closure")
N_ARTIC = len(ARTIC_PARAMS)

VISEMES = ("i", "a", "o", "f", "u", "m", "neutral")

# phone: (viseme, targets in ARTIC_PARAMS order, lip dominance, jaw dominance)
_TABLE: dict[str, tuple[str, tuple[float, ...], float, float]] = {
    # vowels
    "iy": ("i", (0.15, 0.20, 0.85, 0.00, 0.10, 0, 0), 0.80, 0.70),
    "ih": ("i", (0.22, 0.28, 0.55, 0.00, 0.05, 0, 0), 0.70, 0.70),
    "ey": ("i", (0.28, 0.32, 0.60, 0.00, 0.05, 0, 0), 0.70, 0.70),
    "eh": ("i", (0.38, 0.42, 0.40, 0.00, 0.05, 0, 0), 0.70, 0.75),
    "ae": ("a", (0.62, 0.58, 0.45, 0.00, 0.10, 0, 0), 0.75, 0.85),
    "aa": ("a", (0.85, 0.75, 0.10, 0.05, 0.05, 0, 0), 0.80, 0.90),
    "ah": ("a", (0.52, 0.52, 0.15, 0.00, 0.05, 0, 0), 0.65, 0.80),
    "ax": ("a", (0.32, 0.32, 0.10, 0.00, 0.00, 0, 0), 0.45, 0.60),
    "ay": ("a", (0.70, 0.62, 0.35, 0.00, 0.05, 0, 0), 0.75, 0.85),
    "aw": ("a", (0.68, 0.62, 0.00, 0.35, 0.05, 0, 0), 0.75, 0.85),
    "ao": ("o", (0.62, 0.55, 0.00, 0.55, 0.05, 0, 0), 0.80, 0.85),
    "ow": ("o", (0.42, 0.42, 0.00, 0.75, 0.05, 0, 0), 0.85, 0.75),
    "oy": ("o", (0.45, 0.42, 0.10, 0.55, 0.05, 0, 0), 0.80, 0.75),
    "uw": ("u", (0.15, 0.18, 0.00, 0.95, 0.00, 0, 0), 0.90, 0.60),
    "uh": ("u", (0.25, 0.28, 0.00, 0.60, 0.00, 0, 0), 0.75, 0.65),
    "er": ("u", (0.25, 0.28, 0.00, 0.50, 0.20, 0, 0), 0.70, 0.65),
    # bilabials and labiodentals: full lip dominance
    "p": ("m", (0.10, 0.00, 0.00, 0.00, 0.00, 0, 1), 1.00, 0.60),
    "b": ("m", (0.10, 0.00, 0.00, 0.00, 0.00, 0, 1), 1.00, 0.60),
    "m": ("m", (0.10, 0.00, 0.00, 0.00, 0.00, 0, 1), 1.00, 0.60),
    "f": ("f", (0.12, 0.05, 0.05, 0.00, 0.30, 1, 0), 1.00, 0.60),
    "v": ("f", (0.12, 0.05, 0.05, 0.00, 0.30, 1, 0), 1.00, 0.60),
    # rounded consonants
    "w": ("u", (0.10, 0.12, 0.00, 1.00, 0.00, 0, 0), 0.90, 0.50),
    "r": ("u", (0.15, 0.20, 0.00, 0.50, 0.10, 0, 0), 0.60, 0.40),
    "sh": ("u", (0.15, 0.20, 0.00, 0.60, 0.15, 0, 0), 0.70, 0.50),
    "zh": ("u", (0.15, 0.20, 0.00, 0.60, 0.15, 0, 0), 0.70, 0.50),
    "ch": ("u", (0.15, 0.18, 0.00, 0.55, 0.15, 0, 0), 0.70, 0.50),
    "jh": ("u", (0.15, 0.18, 0.00, 0.55, 0.15, 0, 0), 0.70, 0.50),
    # lingual consonants: little lip dominance
    "s": ("neutral", (0.10, 0.15, 0.35, 0.00, 0.00, 0, 0), 0.35, 0.60),
    "z": ("neutral", (0.10, 0.15, 0.35, 0.00, 0.00, 0, 0), 0.35, 0.60),
    "th": ("neutral", (0.18, 0.25, 0.10, 0.00, 0.05, 0, 0), 0.30, 0.40),
    "dh": ("neutral", (0.18, 0.25, 0.10, 0.00, 0.05, 0, 0), 0.25, 0.35),
    "t": ("neutral", (0.15, 0.20, 0.10, 0.00, 0.00, 0, 0), 0.15, 0.40),
    "d": ("neutral", (0.15, 0.20, 0.10, 0.00, 0.00, 0, 0), 0.15, 0.40),
    "n": ("neutral", (0.15, 0.20, 0.10, 0.00, 0.00, 0, 0), 0.12, 0.35),
    "l": ("neutral", (0.22, 0.25, 0.10, 0.00, 0.00, 0, 0), 0.12, 0.35),
    "dx": ("neutral", (0.20, 0.22, 0.05, 0.00, 0.00, 0, 0), 0.08, 0.25),
    "el": ("neutral", (0.25, 0.25, 0.05, 0.05, 0.00, 0, 0), 0.15, 0.35),
    "en": ("neutral", (0.15, 0.18, 0.05, 0.00, 0.00, 0, 0), 0.12, 0.30),
    "k": ("neutral", (0.22, 0.25, 0.05, 0.00, 0.00, 0, 0), 0.10, 0.40),
    "g": ("neutral", (0.22, 0.25, 0.05, 0.00, 0.00, 0, 0), 0.10, 0.40),
    "ng": ("neutral", (0.20, 0.22, 0.05, 0.00, 0.00, 0, 0), 0.10, 0.35),
    "y": ("i", (0.15, 0.18, 0.60, 0.00, 0.05, 0, 0), 0.40, 0.40),
    "hh": ("neutral", (0.30, 0.35, 0.05, 0.00, 0.00, 0, 0), 0.05, 0.10),
    # silence: the face relaxes to rest
    "sil": ("neutral", (0.00, 0.00, 0.00, 0.00, 0.00, 0, 0), 0.55, 0.55),
}

PHONES: tuple[str, ...] = tuple(_TABLE)
N_PHONES = len(PHONES)
PHONE_INDEX = {p: i for i, p in enumerate(PHONES)}
BILABIALS = frozenset({"p", "b", "m"})
assert N_PHONES == 44, N_PHONES


def viseme(phone: str) -> str:
    """The viseme (``i a o f u m`` or ``neutral``) of a phone class (a :data:`PHONES` label);
    :class:`~groundwork.errors.ParameterError` for any other label."""
    return _TABLE[check_phone(phone)][0]


def check_phone(phone: str, *, source: str = "") -> str:
    """Return ``phone`` if it is one of the 44 classes.

    Parameters
    ----------
    phone : str
        A phone label.
    source : str
        Where it was read (a file, a line), for the message.

    Returns
    -------
    str
        ``phone``, unchanged.

    Raises
    ------
    ParameterError
        ``phone`` is not one of :data:`PHONES`; the message lists them.
    """
    if phone not in PHONE_INDEX:
        where = f" in {source}" if source else ""
        raise ParameterError(
            f"unknown phone {phone!r}{where}; allowed are the 44 classes: {' '.join(PHONES)}"
        )
    return phone


# Symbols of other phone sets (festival, TIMIT, ARPAbet's extras) and their classes.
_SILENCES = {"pau", "sil", "h#", "ssil", "sp", "brth", ""}
_OTHER = {"axr": "er", "em": "m", "hv": "hh", "nx": "n", "ix": "ih", "ux": "uw"}


def phone_class(symbol: str, *, source: str = "") -> str:
    """The class of an ARPAbet or festival phone symbol.

    Parameters
    ----------
    symbol : str
        Any case, an ARPAbet stress digit allowed: ``AA1`` → ``aa``, ``pau`` → ``sil``,
        ``axr`` → ``er``; silences (``pau sil h# ssil sp brth`` or empty) are ``sil``.
    source : str
        Where it was read (a file, a line), for the message.

    Returns
    -------
    str
        One of :data:`PHONES`.

    Raises
    ------
    CorpusError
        The symbol has no class; the message lists the 44.
    """
    s = re.sub(r"[0-2]$", "", symbol.strip()).lower()
    s = "sil" if s in _SILENCES else _OTHER.get(s, s)
    if s not in PHONE_INDEX:
        where = f" in {source}" if source else ""
        raise CorpusError(f"phone symbol {symbol!r}{where} has no class among the 44: "
                          f"{' '.join(PHONES)}")
    return s


def target_matrix() -> np.ndarray:
    """Articulatory targets, shape (44, 7), rows in :data:`PHONES` order."""
    return np.asarray([_TABLE[p][1] for p in PHONES], dtype=np.float64)


def dominance_matrix() -> np.ndarray:
    """Dominance magnitudes alpha, shape (44, 7): the jaw column uses the jaw dominance, every lip
    parameter the lip dominance."""
    alpha = np.empty((N_PHONES, N_ARTIC))
    for i, p in enumerate(PHONES):
        _, _, lip, jaw = _TABLE[p]
        alpha[i, :] = lip
        alpha[i, 0] = jaw
    return alpha
