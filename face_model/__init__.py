"""Marker layout and mesh, phone classes, corpus I/O, alignment and Motion Units (paper §IV)."""
from face_model.alignment import align_markers, corpus_deformations, speaker_neutrals
from face_model.corpus import Corpus, Utterance, load_corpus
from face_model.errors import CorpusError, NotFittedError, ParameterError, TalkingFaceError
from face_model.layout import LAYOUT_VERSION, FaceLayout, default_layout, mouth_opening
from face_model.motion_units import MotionUnits, fit_corpus_units
from face_model.phones import PHONES, viseme

__all__ = ["align_markers", "corpus_deformations", "speaker_neutrals", "Corpus", "Utterance",
           "load_corpus", "CorpusError", "NotFittedError", "ParameterError", "TalkingFaceError",
           "LAYOUT_VERSION", "FaceLayout", "default_layout", "mouth_opening", "MotionUnits",
           "fit_corpus_units", "PHONES", "viseme"]
