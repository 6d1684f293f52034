"""The IPA symbols of the hama phoneme recogniser, mapped to the project's 44 phone classes.

hama 1.7.0's phoneme model (:mod:`mapping.hama_front`) is multilingual: its output vocabulary
holds 189 symbols besides the CTC blank — English phones, the phones of other languages, tone
letters, diacritics and a few special tokens. Every one of them is written down here, in one of
two kinds:

* a **phone**: one of the 44 classes (:data:`face_model.phones.PHONES`). English IPA takes its
  ARPAbet class as cmudict writes the word (``ɹ`` → ``r``, ``ɝ``/``ɚ``/``ɜ`` → ``er``, ``ɾ`` →
  ``dx``, ``ʔ`` → ``t``, the glottal stop of *button*); a phone of another language takes the
  English class nearest in place of articulation and lip shape, which is what the face shows:
  aspirated and tense stops are their plain stop (``pʰ p͈`` → ``p``), front rounded vowels are
  rounded (``y ʏ`` → ``uw``/``uh``), unrounded back vowels unrounded (``ɯ`` → ``ih``), the
  bilabial fricative and approximant are ``b`` (hama writes English *table* as ``t ̪ a β ̞ l e``),
  glide + vowel tokens (``ja``, ``wi``) their vowel, the longer part;
* **no phone** (:data:`NOT_PHONES`): diacritics and length marks (they modify the phone before
  them), tone letters and numbers, word boundaries, punctuation and the model's special tokens.
  They start no phone: a frame is never labelled with them.

:func:`ipa_class` is the one lookup; a symbol in neither table is an error that names it, and
:func:`check_vocabulary` runs it over a model's whole vocabulary when the model is loaded, so a
new model with a symbol this table lacks is refused before it labels any frame.
"""
from __future__ import annotations

from face_model.phones import PHONE_INDEX
from groundwork.errors import ParameterError

BLANK = "<blank>"  # the CTC blank: handled by the decoder, not a symbol of the table

# symbol -> one of the 44 classes
IPA_CLASSES: dict[str, str] = {
    # English vowels and diphthongs (cmudict's classes)
    "i": "iy", "ɪ": "ih", "e": "ey", "eɪ": "ey", "ɛ": "eh", "æ": "ae", "a": "aa", "ɑ": "aa",
    "ɒ": "aa", "ʌ": "ah", "ɐ": "ah", "ə": "ax", "ɚ": "er", "ɝ": "er", "ɜ": "er", "aɪ": "ay",
    "aʊ": "aw", "ɔ": "ao", "o": "ow", "oʊ": "ow", "ɔɪ": "oy", "u": "uw", "ʊ": "uh",
    "eə": "eh", "ɪə": "ih",
    # other vowels: the nearest English vowel of the same rounding
    "y": "uw", "ʏ": "uh", "ø": "ow", "œ": "ao", "ɵ": "ow", "ʉ": "uw", "ɨ": "ih", "ɯ": "ih",
    "ɯi": "ih", "ɤ": "ah", "ɘ": "ax", "à": "aa", "ã": "aa", "ä": "aa", "å": "ao", "ì": "iy",
    "ĩ": "iy", "ǐ": "iy", "õ": "ow", "ũ": "uw", "ẽ": "eh",
    # glide + vowel tokens: the vowel
    "ja": "aa", "je": "eh", "jo": "ow", "ju": "uw", "jʌ": "ah",
    "wa": "aa", "we": "eh", "wi": "iy", "wʌ": "ah",
    # bilabials and labiodentals
    "p": "p", "pʰ": "p", "p͈": "p", "b": "b", "ɓ": "b", "β": "b", "ʙ": "b", "m": "m", "ɱ": "m",
    "f": "f", "ɸ": "f", "v": "v", "ʋ": "v",
    # dentals, alveolars, post-alveolars
    "θ": "th", "ð": "dh", "s": "s", "s͈": "s", "z": "z", "ẑ": "z", "ʃ": "sh", "ɕ": "sh",
    "ʂ": "sh", "ʒ": "zh", "ʑ": "zh", "ʐ": "zh", "t͡ʃ": "ch", "t͡ɕ": "ch", "t͡ɕʰ": "ch",
    "t͡ɕ͈": "ch", "d͡ʒ": "jh", "t": "t", "tʰ": "t", "t͈": "t", "ʈ": "t", "ʔ": "t", "d": "d",
    "ɖ": "d", "ɗ": "d", "n": "n", "ñ": "n", "ɲ": "n", "l": "l", "ɫ": "l", "ɮ": "l", "ʎ": "l",
    "ɾ": "dx", "ɽ": "dx",
    # rhotics
    "ɹ": "r", "r": "r", "ɻ": "r", "ʀ": "r", "ʁ": "r",
    # velars, palatals, glottals
    "k": "k", "kʰ": "k", "k͈": "k", "c": "k", "g": "g", "ɡ": "g", "ɟ": "g", "ɣ": "g",
    "ŋ": "ng", "ɴ": "ng", "x": "hh", "χ": "hh", "ħ": "hh", "h": "hh", "ɦ": "hh", "ç": "hh",
    # glides
    "j": "y", "ʝ": "y", "ɰ": "y", "w": "w", "ɥ": "w",
}

# symbols that start no phone: diacritics and length (they modify the phone before them), tone
# letters and numbers, word boundaries and punctuation, the model's special tokens
NOT_PHONES: frozenset = frozenset([
    "<pad>", "<sos>", "<eos>", "<unk>", "<wb>", " ", "%", ",", "~", "‿", "一", "不",
    "ʰ", "ʱ", "ʲ", "ʷ", "ˀ", "ː", "ˑ", "˕", "˞", "ˤ", "ᵊ", "ᵝ",
    "\u0303", "\u0306", "\u0308", "\u030a", "\u030c", "\u030d", "\u031a", "\u031d", "\u031e",
    "\u031f", "\u0320", "\u0325", "\u0329", "\u032a", "\u032c", "\u032f", "\u0330", "\u033a",
    "\u033b", "\u0348", "\u034d", "\u035c", "\u0361",
    "¹", "²", "³", "⁰", "⁴", "⁵", "⁻", "⁽", "⁾", "˥", "˦", "˧", "˨", "˩", "꜔",
])

assert not set(IPA_CLASSES) & NOT_PHONES
assert set(IPA_CLASSES.values()) <= set(PHONE_INDEX)


def ipa_class(symbol: str, *, source: str = "the hama recogniser") -> str | None:
    """The phone class of one output symbol, or None for a symbol that starts no phone.

    Raises
    ------
    ParameterError
        For a symbol in neither table, naming it (and ``source``).
    """
    if symbol in IPA_CLASSES:
        return IPA_CLASSES[symbol]
    if symbol in NOT_PHONES:
        return None
    raise ParameterError(f"{source}: output symbol {symbol!r} (U+{ord(symbol[0]):04X}"
                         f"{'…' if len(symbol) > 1 else ''}) is not in the IPA table of "
                         f"mapping/ipa.py; add it to IPA_CLASSES (a phone) or NOT_PHONES")


def check_vocabulary(tokens, *, source: str = "the hama recogniser") -> list[int]:
    """The class index (into :data:`face_model.phones.PHONES`) of every token of a model's
    vocabulary, -1 for the blank and for symbols that start no phone; a symbol the table does
    not cover raises :class:`ParameterError` naming it."""
    out = []
    for t in tokens:
        c = None if t == BLANK else ipa_class(t, source=source)
        out.append(-1 if c is None else PHONE_INDEX[c])
    return out
