"""Faces: the marker layout and mesh, phone classes, the corpus contract, alignment, Motion Units,
keyframes, the MU-constrained tracker, landmark detection and the renderer (paper §IV, §V)."""
from groundwork.lazy import lazy_exports

_EXPORTS = {
    "face_model.alignment": ["align_markers", "corpus_deformations", "speaker_neutrals"],
    "face_model.corpus": ["Corpus", "Utterance", "load_corpus"],
    "face_model.layout": ["LAYOUT_VERSION", "FaceLayout", "default_layout", "mouth_opening"],
    "face_model.motion_units": ["MotionUnits", "fit_corpus_units"],
    "face_model.phones": ["PHONES", "viseme"],
}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)

__all__ = ["align_markers", "corpus_deformations", "speaker_neutrals", "Corpus", "Utterance",
           "load_corpus", "LAYOUT_VERSION", "FaceLayout", "default_layout", "mouth_opening",
           "MotionUnits", "fit_corpus_units", "PHONES", "viseme"]
