"""Faces: the marker layout and mesh, phone classes, the corpus contract, alignment, Motion Units,
keyframes, the MU-constrained tracker, landmark detection and the renderer (paper §IV, §V)."""
from face_model.alignment import align_markers, corpus_deformations, speaker_neutrals
from face_model.corpus import Corpus, Utterance, load_corpus
from face_model.layout import LAYOUT_VERSION, FaceLayout, default_layout, mouth_opening
from face_model.motion_units import MotionUnits, fit_corpus_units
from face_model.phones import PHONES, viseme

__all__ = ["align_markers", "corpus_deformations", "speaker_neutrals", "Corpus", "Utterance",
           "load_corpus", "LAYOUT_VERSION", "FaceLayout", "default_layout", "mouth_opening", "MotionUnits",
           "fit_corpus_units", "PHONES", "viseme"]
