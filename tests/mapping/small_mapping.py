"""One way the mapping tests train a small mapping on the small corpus: through
:func:`mapping.experiment.train_method`, as a run trains it, with any mapping settings."""
import dataclasses
from types import SimpleNamespace

from face_model.motion_units import fit_corpus_units
from mapping import build_dataset, split_masks
from mapping.animator import StreamingAnimator
from mapping.checkpoint import AudioMapping, rest_mups
from mapping.experiment import augmented_copies, recognise_context, train_method
from talkingface.config import Config


def train_small(corpus, *, method: str = "gated_mlp", split: str = "utterance",
                epochs: int = 30, **changes):
    """``mapping`` (an AudioMapping), ``units``, ``data``, ``masks``, the augmented ``copies``
    (``(data, masks)``) and the ``result`` (TrainedMethod) of ``method`` trained with the
    paper's settings changed by ``changes`` (mapping fields) for ``epochs`` epochs at most."""
    cfg = Config()
    mcfg = dataclasses.replace(cfg.mapping, **changes,
                               train=dataclasses.replace(cfg.mapping.train, max_epochs=epochs))
    units, _ = fit_corpus_units(corpus)
    data = build_dataset(corpus, units, recognise_context=recognise_context(mcfg),
                         window_align=mcfg.window_align, mel_fmax_hz=mcfg.mel_fmax_hz)
    masks = split_masks(data, split, seed=cfg.seed)
    copies = augmented_copies(data, masks, mcfg, seed=cfg.seed)
    result = train_method(method, data, masks, mcfg, n_utterance=units.n_utterance,
                          split=split, seed=cfg.seed, copies=copies)
    mapping = AudioMapping(result.mapper, sample_rate=corpus.utterances[0].sample_rate,
                           n_utterance=units.n_utterance, rest_mups=rest_mups(units),
                           window_align=mcfg.window_align, mel_fmax_hz=mcfg.mel_fmax_hz)
    return SimpleNamespace(mapping=mapping, units=units, data=data, masks=masks, copies=copies,
                           result=result)


def stream_frames(animator, y, chunk: int, expression: str = "neutral") -> list:
    """Every frame of ``y`` streamed through a new StreamingAnimator in chunks of ``chunk``
    samples, then flushed."""
    s = StreamingAnimator(animator, expression)
    frames = []
    for i in range(0, len(y), chunk):
        frames += s.push(y[i:i + chunk])
    return frames + s.flush()
