"""A given (real) corpus's Motion Units and neutral faces come from its training sentences only:
the held-out sentences are known before the units are fitted, and are the mapping's."""
from __future__ import annotations

import numpy as np

from face_model.corpus import load_corpus
from face_model.motion_units import MotionUnits
from mapping.dataset import UttData, split_masks
from mapping.experiment import SPLIT_SEED_OFFSET
from talkingface.config import load_config
from talkingface.stages.foundation import fit_units_folder, units_held_out
from talkingface.stages.training import utterance_test_ids


def _cfg(corpus_dir):
    return load_config(None, [f"corpus.source={corpus_dir}", "seed=3"])


def _arrays(path) -> dict:
    u = MotionUnits.load(path)
    out = {k: np.asarray(v).tobytes() for k, v in u.to_arrays()[0].items()}
    out["neutrals"] = repr(u.metadata_.get("neutrals"))
    return out


def test_the_units_stage_holds_out_the_sentences_the_mapping_tests_on(corpus_copy):
    cfg = _cfg(corpus_copy)
    corpus = load_corpus(corpus_copy)
    held = units_held_out(corpus_copy, cfg)
    # the mapping's utterance split (mapping.experiment.run_experiment draws it so)
    data = [UttData(u.utt_id, u.speaker, u.expression, u.text, np.zeros((u.n_frames, 1)),
                    np.zeros((u.n_frames, 1)), np.zeros(u.n_frames, int))
            for u in corpus.utterances]
    masks = split_masks(data, "utterance", train_fraction=cfg.mapping.train_fraction,
                        seed=cfg.seed + SPLIT_SEED_OFFSET)
    tested = [d.utt_id for d, m in zip(data, masks) if not m.any()]
    assert held == tested == utterance_test_ids(corpus, cfg) and 0 < len(held) < len(corpus)
    synthetic = load_config(None, ["seed=3"])
    assert units_held_out(corpus_copy, synthetic) == []  # the paper's Table I: whole corpus


def test_changing_a_held_out_sentence_leaves_the_units_unchanged(corpus_copy, tmp_path):
    cfg = _cfg(corpus_copy)
    held = units_held_out(corpus_copy, cfg)
    fit_units_folder(corpus_copy, tmp_path / "a", cfg, held_out=held)
    before = _arrays(tmp_path / "a" / "motion_units.npz")
    corpus = load_corpus(corpus_copy)
    rng = np.random.default_rng(0)

    def shake(utt_id):
        path = corpus_copy / "markers" / f"{utt_id}.npy"
        m = np.load(path)
        np.save(path, (m + rng.normal(0, 3, m.shape)).astype(np.float32))

    shake(held[0])  # its first frame joins no neutral face, its frames no MU
    fit_units_folder(corpus_copy, tmp_path / "b", cfg, held_out=units_held_out(corpus_copy, cfg))
    assert _arrays(tmp_path / "b" / "motion_units.npz") == before
    trained = next(u.utt_id for u in corpus.utterances if u.utt_id not in held)
    shake(trained)
    fit_units_folder(corpus_copy, tmp_path / "c", cfg, held_out=units_held_out(corpus_copy, cfg))
    after = _arrays(tmp_path / "c" / "motion_units.npz")
    assert after["components"] != before["components"]
    assert after["neutrals"] != before["neutrals"]
