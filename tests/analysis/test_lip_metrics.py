"""The lip and face metrics (issue 13, part 3), each on a hand-computed example."""
import math

import numpy as np
import pytest

from analysis.lip_metrics import (bilabial_segments, closure, dynamics_deviation, lip_metrics,
                                  lip_vertex_error, region_r)
from face_model.phones import PHONE_INDEX
from groundwork.errors import ParameterError

N = 79


def disp(n_frames: int) -> np.ndarray:
    return np.zeros((n_frames, 2 * N))


def put(d, frame: int, marker: int, dx: float, dy: float) -> None:
    d[frame, 2 * marker], d[frame, 2 * marker + 1] = dx, dy


def test_lve_is_the_mean_over_frames_of_the_worst_lip_marker():
    t, e = disp(2), disp(2)
    put(e, 0, 46, 3, 4)  # 5 px: the worst lip marker of frame 0
    put(e, 0, 50, 1, 0)  # 1 px
    put(e, 1, 60, 0, 2)  # 2 px: the worst of frame 1
    put(e, 1, 10, 100, 0)  # a forehead marker: not a lip
    assert lip_vertex_error(t, e) == pytest.approx((5 + 2) / 2)


def test_fdd_is_true_minus_estimated_forehead_dynamics_averaged():
    t1, e1 = disp(4), disp(4)
    for k, r in enumerate([0, 2, 0, 2]):  # marker 0's length: std 1 px
        put(t1, k, 0, 0, r)
    t2, e2 = disp(4), disp(4)
    for k, r in enumerate([0, 4, 0, 4]):  # the estimate's marker 1: std 2 px
        put(e2, k, 1, r, 0)
    put(t1, 0, 30, 9, 9)  # a cheek marker: not in the forehead
    # utterance 1: (1 - 0) / 22; utterance 2: (0 - 2) / 22; mean of the two
    assert dynamics_deviation([t1, t2], [e1, e2]) == pytest.approx((1 / 22 - 2 / 22) / 2)


def test_region_r_sees_only_its_region():
    rng = np.random.default_rng(0)
    t = rng.normal(size=(20, 2 * N))
    e = t.copy()
    cheeks = [2 * m + k for m in range(22, 46) for k in (0, 1)]
    e[:, cheeks] = -t[:, cheeks]  # cheeks reversed
    forehead = [2 * m + k for m in range(0, 22) for k in (0, 1)]
    e[:, forehead] = 0.0  # forehead still
    scale = np.full(2 * N, 2.0)
    assert region_r(t, e, scale, "lips") == pytest.approx(1.0)
    assert region_r(t, e, scale, "cheeks") == pytest.approx(-1.0)
    assert math.isnan(region_r(t, e, scale, "forehead"))
    with pytest.raises(ParameterError, match="unknown region 'nose'; allowed: forehead, cheeks"):
        region_r(t, e, scale, "nose")


def _phones(names):
    return np.array([PHONE_INDEX[p] for p in names])


def _open_track(openings) -> np.ndarray:
    """Displacements whose inner lower lip (71–75) moves down by ``openings`` (px)."""
    d = disp(len(openings))
    for k, o in enumerate(openings):
        for m in range(71, 76):
            put(d, k, m, 0, o)
    return d


def test_closure_counts_bilabial_runs_where_the_lips_meet():
    phones = _phones(["sil", "m", "m", "aa", "b", "aa", "p", "p"])
    assert bilabial_segments(phones) == [(1, 3), (4, 5), (6, 8)]
    d = _open_track([1, 1, -1, 1, 0, 1, 1, 0.5])  # closed in frame 2 (m) and 4 (b), not on p
    assert closure(d, phones) == (2, 3)
    use = np.ones(8, bool)
    use[4] = False  # the b segment's middle frame is in the other part
    assert closure(d, phones, use) == (1, 2)


def test_lip_metrics_pool_over_utterances_and_parts():
    phones = [_phones(["sil", "m", "aa", "aa"]), _phones(["p", "aa", "b", "sil"])]
    truths = [_open_track([0, -2, 5, 5]), _open_track([-2, 5, -2, 0])]  # every run closed
    ests = [_open_track([0, 1, 4, 4]), _open_track([-1, 4, 2, 0])]  # closes 1 of 3
    uses = [np.ones(4, bool), np.ones(4, bool)]
    m = lip_metrics(truths, ests, phones, uses, np.ones(2 * N))
    assert (m.bilabial_segments, m.closure, m.closure_true) == (3, pytest.approx(1 / 3), 1.0)
    assert m.LVE == pytest.approx(np.mean([0, 3, 1, 1, 1, 1, 4, 0]))
    assert math.isnan(m.R_forehead) and m.FDD == 0.0
