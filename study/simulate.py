"""Simulated participants for the perception study (paper §VII-C).

A simulated participant judges the same 27 trials as a real one (``study.design``) and its
answers are written through the same data contract (``study.data``), marked
``simulated=true`` and ``responder_model=flmp-v1``. What it "sees" is computed from the marker
trajectories behind each video; what it "hears" is the sentence's content, because the study's
audio tracks are read calmly and carry no vocal emotion.

What is simulated
-----------------
**Seeing a face** — :class:`study.classifier.ExpressionClassifier`, a frame classifier trained on a corpus:

* features: the markers of every frame with the head motion removed by the glasses markers
  (:func:`face_model.alignment.align_markers`), minus the speaker's neutral face
  (:func:`face_model.alignment.speaker_neutrals`), flattened to 158 values and reduced by a PCA
  (``n_components``, default 10);
* model: multinomial logistic regression (scikit-learn, L2 penalty ``C``, default 1.0);
* labels: each frame gets its utterance's expression. Expressive utterances ramp in from a
  neutral face and relax towards the end, so only the **middle half** of every utterance (frames
  from 25 % to 75 % of its length; ``trim=0.25``) is used for training, for all three classes
  alike — the neutral class then sees the same kind of speech movements. This uses nothing of the
  corpus generator but the fact that expressions are held mid-utterance;
* a query (:meth:`ExpressionClassifier.predict_proba`) is the marker trajectory of one
  animation. It is aligned the same way (stimulus markers are already head-still in the aligned
  frame; aligning them again is a near-identity similarity transform) and the classifier's stored
  neutral face (the mean of the training speakers' neutral faces) is subtracted, unless the
  caller passes the speaker's own. The result is the mean class probability over **all** frames
  of the animation, in the order ``(neutral, smile, sad)``: the whole clip is judged, its neutral
  onset included.

**Deciding** — :class:`FLMPObserver`, Massaro's Fuzzy Logical Model of Perception with a Luce
choice rule. Emotions (the responses other than ``not_sure``) map from expressions
neutral → neutral, smile → happy, sad → sad, and from sentence content normal → neutral,
good → happy, bad → sad.

* visual support of a video: ``v_k = p_k ** gamma`` (``p`` the classifier's probabilities,
  floored at 1e-6), ``gamma`` the participant's visual sensitivity (> 1 sharpens, < 1 flattens);
* audio support of a sentence: ``a_k = rho * [k is the content's emotion] + (1 - rho) / 3``,
  ``rho`` the participant's reliance on the words (0: the words carry nothing, 1: decisive);
* posterior: visual-only ``v_k / sum v``; audio-only ``a_k / sum a``; bimodal (FLMP)
  ``a_k v_k / sum_m a_m v_m``;
* "not sure": with ``p_max`` the largest posterior, the participant answers ``not_sure`` with
  probability ``1 / (1 + exp((p_max - tau) / s))`` — a soft threshold at ``tau`` (a participant
  who is less sure than ``tau`` mostly says so); otherwise the emotion is drawn from the posterior
  (probability matching, as the FLMP's choice rule);
* lapses: with probability ``lambda`` the trial is a lapse and the answer is drawn uniformly from
  the four responses, whatever the stimulus;
* response time (seconds, the ``rt_s`` column): lognormal,
  ``log rt = log(rt_median) + slowing * H + sd * z``, ``H`` the entropy of the posterior divided
  by log 3 (0: certain, 1: uniform; a lapse counts as H = 1), ``z`` standard normal.

Parameters and their population distributions (:class:`PopulationParams`)
-------------------------------------------------------------------------
==========================  =================================  ====================================
participant parameter       meaning                            distribution over participants
==========================  =================================  ====================================
``visual_sensitivity``      gamma, exponent on the classifier  lognormal: median 1.0, log-sd 0.5
``content_reliance``        rho, weight of the words           Beta(4, 2) (mean 0.67)
``not_sure_threshold``      tau, soft threshold on p_max       Uniform(0.35, 0.60)
``not_sure_slope``          s, width of the soft threshold     0.03 for everyone
``lapse_rate``              lambda, uniform-guess probability  Beta(1, 49) (mean 0.02)
``rt_median_s``             median response time when certain  lognormal: median 1.2 s, log-sd 0.25
``rt_uncertainty_slowing``  log-rt added at full uncertainty   0.4 for everyone
``rt_log_sd``               trial-to-trial log-rt noise        0.3 for everyone
==========================  =================================  ====================================

These values are generic choices (a classifier taken as it is on average, words that lean
clearly but not decisively, rare lapses, about a second per answer). **They are not tuned to
reproduce the paper's tallies (Tables III–VII) or any other result**: the simulation shows what
the stimuli and this observer model imply, so that a difference between the synthetic and the
real face can only come from the faces themselves.

Reproducibility
---------------
Every random choice is drawn from ``numpy`` generators seeded from ``np.random.SeedSequence``:
participant ``i``'s parameters and answers come from child ``i`` of ``SeedSequence(seed)``
(adding participants does not change the earlier ones); the allocation list and the trial orders
come from ``study_seed`` exactly as for real participants. Simulated rows carry a blank
``timestamp`` (no session happened at any time), so one seed reproduces every data file byte for
byte. Simulated participants are ``SIM01``, ``SIM02``, …; a study folder that holds a slot of
any other participant is refused (simulated and real data are kept in separate folders), and
nothing that exists is ever overwritten.

An interrupted simulation (a crash, Ctrl-C) is resumed by running it again with the same
settings: the participants already complete are kept, and a participant cut short is
completed, so the folder ends up byte for byte as an uninterrupted run would have left it.
Every file already there is first checked against what this simulation writes; a file written
with other settings (another seed, other stimuli …) is refused before anything is written.
"""
from __future__ import annotations

import platform
from dataclasses import asdict, dataclass
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from groundwork.errors import ParameterError
from study.classifier import (  # noqa: F401  (ExpressionClassifier, visual_evidence: re-exported)
    ExpressionClassifier,
    is_finite_number,
    visual_evidence,
)
from study.data import Allocation, data_path, sidecar_path, write_dataset_description
from study.design import (
    AUDIO_EMOTION,
    BLOCKS,
    EMOTION_OF,
    RESPONSES,
    SENTENCES,
    Trial,
    check_participant_id,
)
from study.simulated_files import RESPONDER_MODEL, SimulatedParticipant, check_allocation
from study.stimuli import manifest_digest

EMOTIONS = ("neutral", "happy", "sad")  # the responses other than not_sure, in class order
EXPRESSION_EMOTION, CONTENT_EMOTION = EMOTION_OF, AUDIO_EMOTION  # study.design's mappings
DEFAULT_KEYS = ("n", "h", "s", "u")  # neutral, happy, sad, not sure (the study's default keys)
PARTICIPANT_PREFIX = "SIM"
_PROB_FLOOR = 1e-6


# --------------------------------------------------------------------------- the observers

def _check_range(name, value, lo, hi, *, lo_open=False, hi_open=False):
    ok = is_finite_number(value) and (value > lo if lo_open else value >= lo) and \
        (value < hi if hi_open else value <= hi)
    if not ok:
        lb, rb = "(" if lo_open else "[", ")" if hi_open else "]"
        raise ParameterError(f"{name} is {value!r}; allowed: {lb}{lo}, {hi}{rb}")


@dataclass(frozen=True)
class ObserverParams:
    """One simulated participant's parameters (meanings in the module text)."""

    visual_sensitivity: float
    content_reliance: float
    not_sure_threshold: float
    not_sure_slope: float
    lapse_rate: float
    rt_median_s: float
    rt_uncertainty_slowing: float
    rt_log_sd: float

    def __post_init__(self):
        _check_range("visual_sensitivity", self.visual_sensitivity, 0, np.inf, lo_open=True,
                     hi_open=True)
        _check_range("content_reliance", self.content_reliance, 0, 1)
        _check_range("not_sure_threshold", self.not_sure_threshold, 0, 1)
        _check_range("not_sure_slope", self.not_sure_slope, 0, np.inf, lo_open=True,
                     hi_open=True)
        _check_range("lapse_rate", self.lapse_rate, 0, 1)
        _check_range("rt_median_s", self.rt_median_s, 0, np.inf, lo_open=True, hi_open=True)
        _check_range("rt_uncertainty_slowing", self.rt_uncertainty_slowing, 0, np.inf,
                     hi_open=True)
        _check_range("rt_log_sd", self.rt_log_sd, 0, np.inf, hi_open=True)


@dataclass(frozen=True)
class PopulationParams:
    """Distributions of the participant parameters (table in the module text). Not tuned to the
    paper's tallies."""

    visual_sensitivity_median: float = 1.0  # lognormal
    visual_sensitivity_log_sd: float = 0.5
    content_reliance_beta: tuple = (4.0, 2.0)  # Beta(a, b)
    not_sure_threshold_range: tuple = (0.35, 0.60)  # Uniform(lo, hi)
    not_sure_slope: float = 0.03  # fixed
    lapse_rate_beta: tuple = (1.0, 49.0)  # Beta(a, b)
    rt_median_s: float = 1.2  # lognormal: median of the participants' medians
    rt_median_log_sd: float = 0.25
    rt_uncertainty_slowing: float = 0.4  # fixed
    rt_log_sd: float = 0.3  # fixed

    def __post_init__(self):
        _check_range("visual_sensitivity_median", self.visual_sensitivity_median, 0, np.inf,
                     lo_open=True, hi_open=True)
        for name in ("visual_sensitivity_log_sd", "rt_median_log_sd"):
            _check_range(name, getattr(self, name), 0, np.inf, hi_open=True)
        for name in ("content_reliance_beta", "lapse_rate_beta"):
            v = getattr(self, name)
            if len(v) != 2 or not all(is_finite_number(x) and x > 0 for x in v):
                raise ParameterError(f"{name} is {v!r}; allowed: two positive numbers (a, b)")
        r = tuple(self.not_sure_threshold_range)
        if len(r) != 2 or not all(is_finite_number(x) for x in r) or not 0 <= r[0] <= r[1] <= 1:
            raise ParameterError(f"not_sure_threshold_range is {self.not_sure_threshold_range!r}"
                                 "; allowed: (lo, hi) with 0 <= lo <= hi <= 1")
        ObserverParams(1.0, 0.5, 0.5, self.not_sure_slope, 0.0, self.rt_median_s,
                       self.rt_uncertainty_slowing, self.rt_log_sd)  # checks the fixed values

    def draw(self, rng: np.random.Generator) -> ObserverParams:
        """One participant's parameters (always the same number of draws, in this order)."""
        gamma = self.visual_sensitivity_median * np.exp(
            self.visual_sensitivity_log_sd * rng.standard_normal())
        rho = rng.beta(*self.content_reliance_beta)
        tau = rng.uniform(*self.not_sure_threshold_range)
        lapse = rng.beta(*self.lapse_rate_beta)
        rt = self.rt_median_s * np.exp(self.rt_median_log_sd * rng.standard_normal())
        return ObserverParams(visual_sensitivity=float(gamma), content_reliance=float(rho),
                              not_sure_threshold=float(tau), not_sure_slope=self.not_sure_slope,
                              lapse_rate=float(lapse), rt_median_s=float(rt),
                              rt_uncertainty_slowing=self.rt_uncertainty_slowing,
                              rt_log_sd=self.rt_log_sd)


def _support(probs, name: str) -> np.ndarray:
    p = np.asarray(probs, dtype=np.float64)
    if p.shape != (3,) or not np.all(np.isfinite(p)) or np.any(p < 0) or p.sum() <= 0:
        raise ParameterError(f"visual evidence of {name} must be 3 non-negative probabilities "
                             f"(neutral, smile, sad), got {probs!r}")
    return p / p.sum()


class FLMPObserver:
    """One simulated participant (FLMP with "not sure" and lapses; see the module text).

    Parameters
    ----------
    params : ObserverParams
    seed : int
        Seeds the answers (``np.random.SeedSequence(seed)``); the same seed and trials give the
        same answers.
    """

    def __init__(self, params: ObserverParams, seed):
        if not isinstance(params, ObserverParams):
            raise ParameterError(f"params must be ObserverParams, got {type(params).__name__}")
        self.params = params
        self.seed = int(seed)
        self._rng = np.random.default_rng(np.random.SeedSequence(self.seed))

    def visual_support(self, probs, name: str = "the stimulus") -> np.ndarray:
        """``v_k = p_k ** gamma`` of the classifier's (neutral, smile, sad) probabilities."""
        p = np.maximum(_support(probs, name), _PROB_FLOOR)
        return p ** self.params.visual_sensitivity

    def audio_support(self, audio: str) -> np.ndarray:
        """``a_k`` of a sentence (``normal``, ``good``, ``bad``) over :data:`EMOTIONS`."""
        if audio not in CONTENT_EMOTION:
            raise ParameterError(f"audio {audio!r}; allowed: {', '.join(CONTENT_EMOTION)}")
        rho = self.params.content_reliance
        a = np.full(3, (1.0 - rho) / 3.0)
        a[EMOTIONS.index(CONTENT_EMOTION[audio])] += rho
        return a

    def posterior(self, trial: Trial, visual: dict) -> np.ndarray:
        """P(emotion | stimulus) over ``EMOTIONS`` for one trial (before not-sure and lapses);
        ``visual``: stimulus id → the classifier's (neutral, smile, sad) probabilities."""
        if trial.block not in BLOCKS:
            raise ParameterError(f"trial block {trial.block!r}; allowed: {', '.join(BLOCKS)}")
        s = np.ones(3)
        if trial.block in ("visual", "bimodal"):
            if trial.stimulus_id not in visual:
                raise ParameterError(f"no visual evidence for stimulus {trial.stimulus_id!r} "
                                     "(compute it with visual_evidence)")
            s = s * self.visual_support(visual[trial.stimulus_id], repr(trial.stimulus_id))
        if trial.block in ("audio", "bimodal"):
            s = s * self.audio_support(trial.audio)
        return s / s.sum()

    def respond(self, trial: Trial, visual: dict) -> tuple[str, float]:
        """The answer (one of ``RESPONSES``) and the response time in seconds (``visual`` as
        for :meth:`posterior`); draws from the observer's own random stream."""
        post = self.posterior(trial, visual)
        u = self._rng.random(4)  # lapse?, lapse answer, not sure?, emotion
        z = self._rng.standard_normal()
        p = self.params
        if u[0] < p.lapse_rate:
            response, uncertainty = RESPONSES[min(int(u[1] * len(RESPONSES)), 3)], 1.0
        else:
            pmax = float(post.max())
            x = (pmax - p.not_sure_threshold) / p.not_sure_slope
            p_not_sure = 1.0 / (1.0 + np.exp(min(x, 700.0)))
            if u[2] < p_not_sure:
                response = "not_sure"
            else:
                k = int(np.searchsorted(np.cumsum(post), u[3] * post.sum(), side="right"))
                response = EMOTIONS[min(k, 2)]
            nz = post[post > 0]
            uncertainty = float(-(nz * np.log(nz)).sum() / np.log(3))
        rt = p.rt_median_s * np.exp(p.rt_uncertainty_slowing * uncertainty + p.rt_log_sd * z)
        return response, float(rt)


def make_observers(n: int, seed: int, population: PopulationParams = PopulationParams()
                   ) -> list[FLMPObserver]:
    """``n`` participants: participant ``i`` from child ``i`` of ``SeedSequence(seed)`` (its
    parameters from one grandchild, its answers from the other); see :func:`make_observer`."""
    check_n(n)
    return [make_observer(i, seed, population) for i in range(int(n))]


def check_n(n) -> int:
    """``n`` as the number of simulated participants, or a ParameterError."""
    if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or n < 1:
        raise ParameterError(f"the number of simulated participants must be a positive integer, "
                             f"got {n!r}")
    return int(n)


def make_observer(i: int, seed: int, population: PopulationParams = PopulationParams()
                  ) -> FLMPObserver:
    """Participant ``i`` alone: child ``i`` of ``SeedSequence(seed)`` is
    ``SeedSequence(seed, spawn_key=(i,))``, so a study of a million participants draws each one
    when it is simulated rather than all of them first."""
    if not isinstance(population, PopulationParams):
        raise ParameterError(f"population must be PopulationParams, got "
                             f"{type(population).__name__}")
    ss_params, ss_answers = np.random.SeedSequence(int(seed), spawn_key=(int(i),)).spawn(2)
    params = population.draw(np.random.default_rng(ss_params))
    return FLMPObserver(params, int(ss_answers.generate_state(2, np.uint64)[0] >> 1))


def responder(observer: FLMPObserver, visual: dict):
    """A function ``trial -> (response, rt_s)`` answering as ``observer`` (for the session
    runner, which injects these answers instead of waiting for keys)."""
    def respond(trial: Trial) -> tuple[str, float]:
        return observer.respond(trial, visual)

    respond.responder_model = RESPONDER_MODEL
    return respond


# --------------------------------------------------------------------------- the study

def participant_ids(n: int) -> list[str]:
    """``SIM01`` … (zero-padded to the width of ``n``, at least two digits)."""
    width = max(2, len(str(n)))
    return [check_participant_id(f"{PARTICIPANT_PREFIX}{i:0{width}d}") for i in range(1, n + 1)]


def _versions() -> dict:
    out = {"python": platform.python_version()}
    for name in ("numpy", "scipy", "scikit-learn"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            continue
    return out


def simulate_study(study_dir, stimuli: dict, classifier: ExpressionClassifier, *, n: int,
                   seed: int, study_seed: int, progress: bool = False,
                   population: PopulationParams = PopulationParams(),
                   keys: tuple = DEFAULT_KEYS) -> dict:
    """Run ``n`` simulated participants through the study into ``study_dir``, or resume an
    interrupted run (see the module text).

    Parameters
    ----------
    study_dir : path
        The study data folder (``study.data`` layout). Its allocation list is created with
        ``(n, study_seed)``, or reused if it is that list. Refused before anything is written:
        a folder whose list differs, that holds a slot of a participant who is not simulated,
        whose ``SIM`` files are not those this simulation writes, or whose simulation is
        complete already (simulations are never overwritten or extended).
    stimuli : dict
        :func:`study.stimuli.load_manifest`'s stimulus set (video markers are needed).
    classifier : ExpressionClassifier
        Fitted; it turns every video's markers into visual evidence.
    n : int
        Number of simulated participants (``SIM01`` …).
    seed : int
        Seeds the participants' parameters and answers.
    study_seed : int
        The study seed: allocation list and trial orders, as for real participants.
    progress : bool
        A progress bar over the participants (on stderr).
    population : PopulationParams
    keys : tuple of 4 str
        The response keys recorded for neutral, happy, sad and not sure.

    Returns
    -------
    dict: ``n``, ``participants``, ``sequences`` (count per sequence), ``study_dir``,
    ``data`` and ``sidecars`` (paths), ``dataset_description``, ``allocation``,
    ``responder_model``, ``kept`` (participants complete before this call) and ``resumed``
    (participants cut short by an interruption and completed by this call).
    """
    _check_study_arguments(n=n, seed=seed, population=population, classifier=classifier,
                           keys=keys)
    visual = visual_evidence(classifier, stimuli)
    pids = participant_ids(n)
    study_dir = Path(study_dir)
    key_of = dict(zip(RESPONSES, keys))
    common = _shared_sidecar(seed=seed, study_seed=study_seed, population=population,
                             classifier=classifier, stimuli=stimuli, visual=visual,
                             key_of=key_of)

    def make(i, slot):
        observer = make_observer(i, seed, population)
        return SimulatedParticipant(
            pids[i], slot, responder(observer, visual), study_seed=int(study_seed),
            key_of=key_of, sidecar={"participant_index": i, "observer_seed": observer.seed,
                                    "observer": asdict(observer.params)}, common=common)

    alloc = Allocation(study_dir)
    found, kept, resumed = _earlier_participants(study_dir, alloc, pids, make, n=n,
                                                 study_seed=study_seed)
    alloc.create(int(n), int(study_seed))
    description = write_dataset_description(study_dir, name="talkingface emotion perception "
                                            "study (simulated participants)", simulated=True)
    counts, data_files, sidecars = _write_participants(
        study_dir, alloc, pids, found, make, progress=progress, kept=kept, resumed=resumed)
    return {"n": int(n), "participants": pids, "sequences": counts, "study_dir": study_dir,
            "data": data_files, "sidecars": sidecars, "dataset_description": description,
            "allocation": alloc.path, "responder_model": RESPONDER_MODEL, "kept": kept,
            "resumed": resumed}


def _check_study_arguments(*, n, seed, population, classifier, keys) -> None:
    """The refusals of :func:`simulate_study` that need no file (made before anything is
    computed or written)."""
    if len(keys) != len(RESPONSES) or len(set(keys)) != len(keys):
        raise ParameterError(f"keys must be {len(RESPONSES)} distinct keys for "
                             f"{', '.join(RESPONSES)}, got {keys!r}")
    check_n(n)
    make_observer(0, seed, population)  # checks the population before anything is written
    if not isinstance(classifier, ExpressionClassifier):
        raise ParameterError(f"classifier must be an ExpressionClassifier, got "
                             f"{type(classifier).__name__}")


def _shared_sidecar(*, seed, study_seed, population, classifier, stimuli, visual,
                    key_of) -> dict:
    """The sidecar fields every simulated participant shares: what the simulation ran with."""
    return {"simulated": True, "responder_model": RESPONDER_MODEL, "simulation_seed": int(seed),
            "study_seed": int(study_seed), "population": asdict(population),
            "classifier": classifier.describe(), "stimuli_digest": manifest_digest(stimuli),
            "visual_evidence": {sid: [round(float(x), 6) for x in p]
                                for sid, p in visual.items()},
            "sentences": SENTENCES, "keys": key_of, "versions": _versions()}


def _earlier_participants(study_dir: Path, alloc: Allocation, pids: list[str], make, *, n,
                          study_seed) -> tuple[dict, list[str], list[str]]:
    """What an earlier, interrupted call left in ``study_dir``, checked before anything is
    written: the participants found (pid → :class:`SimulatedParticipant`), those complete
    (kept) and those cut short (resumed). Refuses a folder that is not this simulation's, or
    whose simulation is complete."""
    rows = check_allocation(alloc, pids, n=int(n), study_seed=int(study_seed))
    held = {r["participant_id"]: r for r in rows}
    found, kept, resumed = {}, [], []
    for i, pid in enumerate(pids):
        files = [p for p in (data_path(study_dir, pid), sidecar_path(study_dir, pid))
                 if p.exists()]
        if files and pid not in held:
            raise ParameterError(f"{', '.join(map(str, files))} exist(s), but {pid} holds no "
                                 f"slot in {alloc.path}; these are not the files of an "
                                 "interrupted simulation: use a new study folder")
        if pid in held:  # from an earlier, interrupted call
            found[pid] = make(i, held[pid])
            complete = found[pid].check_files(study_dir)
            (kept if complete and held[pid]["status"] == "complete" else resumed).append(pid)
    if len(kept) == len(pids):
        raise ParameterError(f"the simulation in {study_dir} is complete ({n} participants); "
                             "simulations are never overwritten or extended: use a new study "
                             "folder")
    return found, kept, resumed


def _write_participants(study_dir: Path, alloc: Allocation, pids: list[str], found: dict,
                        make, *, progress: bool, kept: list, resumed: list
                        ) -> tuple[dict, list[Path], list[Path]]:
    """Complete every participant's files and slot, in order (those ``found`` as they are,
    the others assigned a slot now); returns the count per sequence and the data and sidecar
    paths."""
    counts = {s: 0 for s in ("SR", "RS")}
    data_files, sidecars = [], []
    bar = tqdm(pids, desc="simulated participants", unit="participant", disable=not progress)
    for i, pid in enumerate(bar):
        who = found.get(pid) or make(i, alloc.assign(pid))
        who.write(study_dir, alloc)
        counts[who.sequence] += 1
        data_files.append(data_path(study_dir, pid))
        sidecars.append(sidecar_path(study_dir, pid))
        if kept or resumed:
            bar.set_postfix(kept=len(kept), resumed=len(resumed))
    return counts, data_files, sidecars


__all__ = ["RESPONDER_MODEL", "EMOTIONS", "EXPRESSION_EMOTION", "CONTENT_EMOTION",
           "ExpressionClassifier", "ObserverParams", "PopulationParams", "FLMPObserver",
           "make_observers", "make_observer", "check_n", "visual_evidence", "responder", "participant_ids",
           "simulate_study"]
