"""The synthetic audio-visual corpus: text, speech with phone timing, coarticulated 2D marker
faces with expressions, speakers and head motion (paper §IV-A, §VI, §VII-A)."""
from data_synth.backends import voice_speakers
from data_synth.generate import plan_corpus, synthesize_corpus
from data_synth.text import builtin_sentences, read_sentences

__all__ = ["plan_corpus", "synthesize_corpus", "builtin_sentences", "read_sentences",
           "voice_speakers"]
