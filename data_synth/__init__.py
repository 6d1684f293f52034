"""The synthetic audio-visual corpus: text, speech with phone timing, coarticulated 2D marker
faces with expressions, speakers and head motion (paper §IV-A, §VI, §VII-A)."""
from groundwork.lazy import lazy_exports

_EXPORTS = {
    "data_synth.backends": ["voice_speakers"],
    "data_synth.generate": ["plan_corpus", "synthesize_corpus"],
    "data_synth.text": ["builtin_sentences", "read_sentences"],
}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

__all__ = ["plan_corpus", "synthesize_corpus", "builtin_sentences", "read_sentences",
           "voice_speakers"]
