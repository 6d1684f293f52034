"""What a simulated participant sees: an expression classifier on marker deformations.

:class:`ExpressionClassifier` is trained on a corpus (every frame's markers with the head
motion removed by the glasses markers, minus the speaker's neutral face, a PCA, a multinomial
logistic regression; only the middle half of each utterance, where its expression is held) and
judges a whole animation by its mean class probability. :func:`visual_evidence` applies it to
the marker trajectories behind every video of a stimulus set. The observers of
:mod:`study.simulate` take these probabilities as their visual evidence, so a weaker mapping
gives a less readable synthetic face. :func:`observer_classifier` is the classifier every study
command uses: trained on the run's corpus beside the stimuli (:func:`classifier_corpus`).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from sklearn.decomposition import PCA
from sklearn.linear_model import LogisticRegression
from sklearn.pipeline import make_pipeline

from face_model.alignment import align_markers, flatten, speaker_neutrals
from face_model.corpus import load_corpus
from groundwork.errors import NotFittedError, ParameterError
from groundwork.numerics import single_threaded
from study.design import AUDIO, EXPRESSIONS, FACES, stimulus_id


def is_finite_number(value) -> bool:
    """A real, finite number (not a bool)."""
    return isinstance(value, (int, float, np.integer, np.floating)) and \
        not isinstance(value, bool) and bool(np.isfinite(value))


class ExpressionClassifier:
    """Frame-wise expression classifier on aligned marker deformations (see the module text).

    Parameters
    ----------
    n_components : int
        PCA dimensions kept (at most the number of training frames and 158).
    C : float
        Inverse L2 penalty of the logistic regression.
    trim : float in [0, 0.5)
        Fraction of every training utterance dropped at each end (its expression ramps in and
        out there).
    """

    classes = EXPRESSIONS  # ("neutral", "smile", "sad")

    def __init__(self, n_components: int = 10, C: float = 1.0, trim: float = 0.25):
        if not isinstance(n_components, (int, np.integer)) or n_components < 1:
            raise ParameterError(f"n_components must be a positive integer, got {n_components!r}")
        if not is_finite_number(C) or not C > 0:
            raise ParameterError(f"C must be a positive number, got {C!r}")
        if not is_finite_number(trim) or not 0.0 <= trim < 0.5:
            raise ParameterError(f"trim must be in [0, 0.5), got {trim!r}")
        self.n_components = int(n_components)
        self.C = float(C)
        self.trim = float(trim)
        self.model_ = None

    def _features(self, markers, neutral: np.ndarray) -> np.ndarray:
        return flatten(align_markers(markers) - neutral[None])

    @single_threaded
    def fit(self, corpus, *, seed: int) -> "ExpressionClassifier":
        """Train on every utterance of ``corpus`` (a loaded :class:`face_model.corpus.Corpus`)."""
        utts = list(corpus.utterances)
        absent = [e for e in self.classes if not any(u.expression == e for u in utts)]
        if absent:
            raise ParameterError(f"the corpus at {getattr(corpus, 'root', '?')} has no "
                                 f"{', '.join(absent)} utterance; the expression classifier "
                                 f"needs all of {', '.join(self.classes)}")
        neutrals = speaker_neutrals(corpus)
        X, y = [], []
        for u in utts:
            f = self._features(u.markers, neutrals[u.speaker])
            n = len(f)
            lo, hi = int(np.floor(self.trim * n)), n - int(np.floor(self.trim * n))
            if hi <= lo:
                lo, hi = 0, n
            X.append(f[lo:hi])
            y.append(np.full(hi - lo, self.classes.index(u.expression)))
        X, y = np.concatenate(X), np.concatenate(y)
        k = min(self.n_components, len(X), X.shape[1])
        self.seed_ = int(seed)
        self.model_ = make_pipeline(
            PCA(n_components=k, svd_solver="full"),
            LogisticRegression(C=self.C, max_iter=5000,  # lbfgs: deterministic; seeded anyway
                               random_state=int(np.random.SeedSequence(self.seed_)
                                                .generate_state(1)[0])))
        self.model_.fit(X, y)
        self.neutral_ = np.mean(np.stack([neutrals[s] for s in sorted(neutrals)]), axis=0)
        self.n_frames_ = int(len(X))
        self.n_utterances_ = len(utts)
        self.speakers_ = sorted(neutrals)
        return self

    def _check_fitted(self):
        if self.model_ is None:
            raise NotFittedError("ExpressionClassifier is not fitted yet: call fit() first")

    def predict_frames(self, markers, *, neutral=None) -> np.ndarray:
        """Class probabilities of every frame, shape (n_frames, 3)."""
        self._check_fitted()
        ref = self.neutral_ if neutral is None else np.asarray(neutral, dtype=np.float64)
        if ref.shape != self.neutral_.shape:
            raise ParameterError(f"neutral must have shape {self.neutral_.shape}, got {ref.shape}")
        proba = self.model_.predict_proba(self._features(markers, ref))
        out = np.zeros((len(proba), len(self.classes)))
        out[:, self.model_.classes_] = proba
        return out

    def predict_proba(self, markers, *, neutral=None) -> np.ndarray:
        """Mean class probability over the frames of one animation, shape (3,), in the order
        ``("neutral", "smile", "sad")``.

        Parameters
        ----------
        markers : ndarray (n_frames, 79, 2)
            Marker positions (pixels; aligned or not, they are aligned by the glasses markers).
        neutral : ndarray (79, 2), optional
            The speaker's aligned neutral face; default: the training speakers' mean.
        """
        p = self.predict_frames(markers, neutral=neutral).mean(0)
        return p / p.sum()

    def describe(self) -> dict:
        """The settings and training summary (written into simulated participants' sidecars)."""
        self._check_fitted()
        return {"model": "pca+multinomial-logistic-regression", "n_components": self.n_components,
                "C": self.C, "trim": self.trim, "seed": self.seed_, "classes": list(self.classes),
                "n_training_frames": self.n_frames_, "n_training_utterances": self.n_utterances_,
                "speakers": self.speakers_}


def classifier_corpus(stimuli_dir) -> Path:
    """The corpus the simulated observers' expression classifier learns from: the run's corpus
    beside ``runs/<name>/stimuli``, else the stimuli's own source sentences."""
    stimuli_dir = Path(stimuli_dir)
    for c in (stimuli_dir.parent / "corpus", stimuli_dir / "source"):
        if (c / "manifest.csv").is_file():
            return c
    raise ParameterError(f"no corpus to train the observers' expression classifier: neither "
                         f"{stimuli_dir.parent / 'corpus'} nor {stimuli_dir / 'source'} exists")


def observer_classifier(stimuli_dir, seed: int) -> ExpressionClassifier:
    """The simulated observers' eyes for a stimulus set: an :class:`ExpressionClassifier` with
    its default settings, fitted with ``seed`` on :func:`classifier_corpus` of ``stimuli_dir``
    (the run's corpus, else the stimuli's source sentences)."""
    return ExpressionClassifier().fit(load_corpus(classifier_corpus(stimuli_dir)), seed=seed)


def visual_evidence(classifier: ExpressionClassifier, stimuli: dict, *,
                    neutral=None) -> dict[str, np.ndarray]:
    """The classifier's probabilities (3,) for every video stimulus, by stimulus id.

    ``stimuli`` is :func:`study.stimuli.load_manifest`'s dict. Every video the design plays must
    be there with its ``markers`` file (the trajectories that drove it)."""
    needed = [stimulus_id(f, e, a) for f in FACES for e in EXPRESSIONS for a in AUDIO]
    absent = [s for s in needed if s not in stimuli]
    if absent:
        raise ParameterError(f"the stimulus set lacks the videos {absent}, which the design plays")
    out = {}
    for sid in sorted(stimuli):
        stim = stimuli[sid]
        if stim.kind != "video":
            continue
        if stim.markers is None:
            raise ParameterError(
                f"video stimulus {sid!r} has no markers file: simulated participants need the "
                "marker trajectories behind every video they judge (the manifest's 'markers' "
                "column)")
        path = Path(stim.markers)
        if not path.is_file():
            raise ParameterError(f"video stimulus {sid!r}: markers file {path} not found")
        try:
            markers = np.load(path, allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            raise ParameterError(f"video stimulus {sid!r}: {path} is not a readable .npy "
                                 f"array ({exc})") from exc
        try:
            out[sid] = classifier.predict_proba(markers, neutral=neutral)
        except ParameterError as exc:
            raise ParameterError(f"video stimulus {sid!r} ({path}): {exc}") from exc
    return out
