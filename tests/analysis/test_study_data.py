"""Study data in, the paper's tables out: known tallies come back exactly, and bad data are
refused naming the file and the row."""
import csv

import numpy as np
import pytest

from analysis.study_data import (
    PAPER_TALLIES,
    load_study_data,
    tallies,
    trials_from_tallies,
    write_study_data,
)
from face_model.errors import ParameterError


@pytest.fixture
def paper_dir(tmp_path):
    return write_study_data(trials_from_tallies(PAPER_TALLIES, seed=3), tmp_path / "study")


def test_the_papers_five_tables_come_back_exactly(paper_dir):
    df = load_study_data(paper_dir)
    assert df["participant_id"].nunique() == 20 and len(df) == 20 * 27
    t = tallies(df)
    assert sorted(t) == ["III", "IV", "V", "VI", "VII"]
    for name, counts in PAPER_TALLIES.items():
        np.testing.assert_array_equal(t[name].counts, counts, err_msg=name)
    assert t["VI"].cell("not_sure", ("sad", "S")) == 8  # the paper's confused subjects
    assert t["VI"].cell("not_sure", ("sad", "R")) == 5
    assert set(t["IV"].column_totals()) == {20}


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_any_consistent_tables_round_trip(seed):
    rng = np.random.default_rng(seed)
    tables = {}
    for name, shape in (("III", 6), ("IV", 3), ("V", 6), ("VI", 6), ("VII", 6)):
        cols = [rng.multinomial(12, rng.dirichlet(np.ones(4))) for _ in range(shape)]
        tables[name] = np.stack(cols, axis=1)
    t = tallies(trials_from_tallies(tables, seed=seed))
    for name in tables:
        np.testing.assert_array_equal(t[name].counts, tables[name])


def _edit(paper_dir, pid, fn):
    path = paper_dir / f"sub-{pid}" / f"sub-{pid}_task-emotion_beh.csv"
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
        fields = list(rows[0])
    rows = fn(rows)
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    return path


@pytest.mark.parametrize("fn, message", [
    (lambda rows: rows[:4] + [dict(rows[4], response="angry")] + rows[5:],
     r"row 6: response 'angry' is not a known code; allowed: neutral, happy, sad, not_sure"),
    (lambda rows: rows[:10] + [rows[9]] + rows[10:],
     r"row 12: trial 9 of T03 duplicated \(first at row 11\)"),
    (lambda rows: rows[:6] + rows[9:],
     r"participant T03 has 0 of 3 judgments in the audio block"),
    (lambda rows: [dict(r, audio="good") if r["block"] == "visual" else r for r in rows],
     r"row 2: a visual trial .* contradicts the design"),
])
def test_bad_data_name_the_file_and_the_row(paper_dir, fn, message):
    path = _edit(paper_dir, "T03", fn)
    with pytest.raises(ParameterError, match=message) as err:
        load_study_data(paper_dir)
    assert str(path) in str(err.value)


def test_an_empty_folder_is_refused(tmp_path):
    with pytest.raises(ParameterError, match="no study data"):
        load_study_data(tmp_path)
    with pytest.raises(ParameterError, match="same participants"):
        trials_from_tallies({**PAPER_TALLIES, "IV": PAPER_TALLIES["IV"] * 0 + 1})
    with pytest.raises(ParameterError, match=r"table IV must be 4 x 3 counts >= 0"):
        trials_from_tallies({**PAPER_TALLIES, "IV": PAPER_TALLIES["IV"][:, :2]})


def test_a_stimulus_judged_twice_is_refused(paper_dir):
    """Six visual trials, but one of them twice and another never: the block size is right,
    the design is not."""
    def twice(rows):
        rows[1] = dict(rows[1], face=rows[0]["face"], expression=rows[0]["expression"])
        return rows
    _edit(paper_dir, "T05", twice)
    with pytest.raises(ParameterError, match=r"row 3: the visual stimulus .* judged twice "
                                             r"\(first at row 2\)"):
        load_study_data(paper_dir)
