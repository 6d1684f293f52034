"""Which stages apply to the run's corpus, and what the others say about why they are off.

A run's corpus is synthesised by :mod:`data_synth` (``corpus.source`` empty) or given: a corpus
folder in the corpus contract, e.g. a real speaker's recordings made from video. Every stage
after the corpus is the same for both (DESIGN.md), except the stages that need what only the
generator gives — they are switched off for a given corpus through their ``enabled`` rule
(:class:`talkingface.stages.base.Stage`), and the report says why (:func:`switched_off`):

* ``tracking`` and ``tracked`` draw the corpus's markers as the synthetic marker face and track
  that video; a given corpus's markers were already found in its own video;
* ``voices`` and ``ceiling`` make corpora of their own by speaking the corpus's sentences again
  with other voices or other generator settings;
* the perception study (``stimuli``, ``study_data``, ``analysis``) shows the generator's "real"
  face and speech beside the animated one, with smile and sad; it needs the generator and both
  expressions (a synthetic corpus without them has it off too).

Everything else runs on any corpus. The *expression parts* inside the stages that run
(expression Motion Units, the expression cascade Υ_k, the smile and sad keyframes, the Fig. 7
faces) are skipped by those stages when the corpus has no utterances of an expression, with the
note of :func:`expression_note` in their ``done.json`` and in the report; a corpus that has an
expression uses it.
"""
from __future__ import annotations

STUDY_EXPRESSIONS = ("smile", "sad")  # the perception study's faces besides neutral

GIVEN_REASONS = {
    "tracking": "it draws the corpus's markers as the synthetic marker face and tracks that "
                "video; a given corpus's markers were found in its own video",
    "tracked": "it draws the corpus's markers as the synthetic marker face and tracks that "
               "video; a given corpus's markers were found in its own video",
    "voices": "it speaks the corpus's sentences again with other synthetic voices "
              "(data_synth), which a given corpus cannot be",
    "ceiling": "its steps make the corpus again with each of the generator's nuisances off, "
               "which a given corpus cannot be",
    "stimuli": "the perception study shows the generator's own face and speech beside the "
               "animated face, in neutral, smile and sad",
    "study_data": "the perception study judges the stimuli, which need the generator",
    "analysis": "Tables III–VII analyse the perception study, which needs the generator",
}
NO_STUDY_REASON = ("the perception study shows smile and sad faces, and synth.expressions "
                   "leaves out {missing}")


def given(cfg) -> bool:
    """Whether the run's corpus is a given folder (``corpus.source``), not synthesised."""
    return bool(cfg.corpus.source)


def synthesised(cfg) -> bool:
    """Whether the run's corpus is synthesised by :mod:`data_synth`."""
    return not given(cfg)


def study_applies(cfg) -> bool:
    """Whether the perception study can run: a synthesised corpus with smile and sad."""
    return synthesised(cfg) and set(STUDY_EXPRESSIONS) <= set(cfg.synth.expressions)


def switched_off(cfg, stages) -> dict:
    """``{stage: why}`` for every stage of ``stages`` (names) that the run's corpus switches
    off; the stages a setting switches off (a grid ``none``, the markers as visual source) are
    not listed."""
    out = {}
    for name in stages:
        if given(cfg) and name in GIVEN_REASONS:
            out[name] = GIVEN_REASONS[name]
        elif name in ("stimuli", "study_data", "analysis") and not study_applies(cfg):
            missing = [e for e in STUDY_EXPRESSIONS if e not in cfg.synth.expressions]
            out[name] = NO_STUDY_REASON.format(missing=" and ".join(missing))
    return out


def expression_note(expressions) -> str | None:
    """What the stages skip on a corpus with the expressions ``expressions`` (those with
    utterances, ``neutral`` included), in one sentence; None when it has smile and sad.

    Examples
    --------
    >>> expression_note(["neutral"])  # doctest: +ELLIPSIS
    'The corpus holds neutral speech only: expression Motion Units, the expression cascade ...'
    """
    present = set(expressions)
    missing = [e for e in STUDY_EXPRESSIONS if e not in present]
    if not missing:
        return None
    if len(missing) == len(STUDY_EXPRESSIONS):
        return ("The corpus holds neutral speech only: expression Motion Units, the expression "
                "cascade and Tables III–VII (the perception study) are skipped.")
    return (f"The corpus holds no {' or '.join(missing)} speech: the Motion Units and the "
            f"expression network of {' and '.join(missing)}, the keyframes (which need smile "
            "and sad) and Tables III–VII (the perception study) are skipped.")
