"""The IPA table of the hama recogniser (issue 29): it covers exactly the installed model's
vocabulary, every symbol it maps lands on one of the 44 phone classes, an uncovered symbol is
refused by name, and the English symbols that matter for the lips take their cmudict class."""
import pytest
from hama.asr import ASRModel

from face_model.phones import PHONE_INDEX, PHONES
from groundwork.errors import ParameterError
from mapping.ipa import BLANK, IPA_CLASSES, NOT_PHONES, check_vocabulary, ipa_class

UNKNOWN = "ʬ"  # U+02AC, bilabial percussive: an IPA letter no hama model writes


@pytest.fixture(scope="module")
def tokens():
    """The installed hama model's output vocabulary (its last token is the CTC blank)."""
    return list(ASRModel().decoder_tokens)


def test_the_table_covers_exactly_the_models_vocabulary(tokens):
    assert tokens[-1] == BLANK
    symbols = set(tokens) - {BLANK}
    assert len(symbols) == len(tokens) - 1  # no symbol twice
    assert not set(IPA_CLASSES) & NOT_PHONES  # each symbol is of one kind only
    # every symbol the model writes is written down, and the table holds nothing the model lacks
    assert symbols - set(IPA_CLASSES) - NOT_PHONES == set()
    assert (set(IPA_CLASSES) | NOT_PHONES) - symbols == set()
    assert BLANK not in IPA_CLASSES and BLANK not in NOT_PHONES


def test_every_phone_symbol_lands_on_one_of_the_44_classes():
    assert set(IPA_CLASSES.values()) <= set(PHONES)
    assert "sil" not in IPA_CLASSES.values()  # a symbol the model writes is never silence


def test_check_vocabulary_gives_a_class_index_per_token(tokens):
    idx = check_vocabulary(tokens)
    assert len(idx) == len(tokens)
    for t, i in zip(tokens, idx):
        if t == BLANK or t in NOT_PHONES:
            assert i == -1, t
        else:
            assert PHONES[i] == IPA_CLASSES[t], t


@pytest.mark.parametrize("symbol", [UNKNOWN, "ʬʬ", "<blank>"])
def test_a_symbol_the_table_lacks_is_refused_by_name(symbol):
    # the blank is the decoder's, not the table's: only check_vocabulary knows it
    with pytest.raises(ParameterError, match=f"output symbol '{symbol}' .* is not in the IPA "
                                             "table of mapping/ipa.py"):
        ipa_class(symbol)


def test_the_refusal_names_the_code_point_and_the_source():
    with pytest.raises(ParameterError, match=r"^model X: output symbol 'ʬ' \(U\+02AC\)"):
        ipa_class(UNKNOWN, source="model X")
    with pytest.raises(ParameterError, match=r"\(U\+02AC…\)"):  # a symbol of several characters
        ipa_class(UNKNOWN + "ː")


def test_a_vocabulary_with_an_uncovered_symbol_is_refused(tokens):
    with pytest.raises(ParameterError, match="the hama recogniser: output symbol 'ʬ'"):
        check_vocabulary(tokens[:-1] + [UNKNOWN, BLANK])
    with pytest.raises(ParameterError, match="^new model: output symbol 'ʬ'"):
        check_vocabulary(["p", "b", UNKNOWN], source="new model")


@pytest.mark.parametrize("symbol, phone", [
    # the lips: bilabials close them, labiodentals touch the lower lip
    ("p", "p"), ("b", "b"), ("m", "m"), ("pʰ", "p"), ("f", "f"), ("v", "v"),
    ("β", "b"),  # hama writes English "table" with a bilabial approximant: the lips still close
    ("ɹ", "r"), ("ɝ", "er"), ("ɚ", "er"),
    ("ʔ", "t"),  # the glottal stop of "button"
    ("ɾ", "dx"), ("θ", "th"), ("ð", "dh"), ("ʃ", "sh"), ("t͡ʃ", "ch"), ("d͡ʒ", "jh"),
    ("w", "w"), ("u", "uw"), ("oʊ", "ow"), ("æ", "ae"), ("ə", "ax"),
])
def test_english_symbols_take_their_cmudict_class(symbol, phone):
    assert ipa_class(symbol) == phone
    assert check_vocabulary([symbol]) == [PHONE_INDEX[phone]]


@pytest.mark.parametrize("symbol", ["ː", "\u032a", "\u031e", "ʰ", "˥", "<wb>", " ", "<pad>"])
def test_diacritics_tones_and_boundaries_start_no_phone(symbol):
    assert ipa_class(symbol) is None
    assert check_vocabulary([symbol]) == [-1]
