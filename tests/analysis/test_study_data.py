"""Study data in, the paper's tables out: known tallies come back exactly, and bad data are
refused naming the file and the row."""
import csv
import json

import numpy as np
import pytest

from analysis.study_data import (
    PAPER_TALLIES,
    load_study_data,
    read_study,
    tallies,
    trials_from_tallies,
    write_study_data,
)
from groundwork.errors import ParameterError
from study.columns import ALLOWED_CODES, COLUMNS, csv_text
from study.data import SessionFile, trial_row
from study.design import RESPONSES, session_trials


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


# --- an incomplete data set is refused, unless allowed -------------------------------------
def _allocation(study, statuses: dict):
    """An allocation list holding the participants of ``study`` (all complete but ``statuses``)."""
    from study.data import ALLOCATION_COLUMNS

    pids = sorted(p.name[4:] for p in study.glob("sub-*")) + \
        [p for p in statuses if not (study / f"sub-{p}").exists()]
    with open(study / "allocation.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=ALLOCATION_COLUMNS, lineterminator="\n")
        w.writeheader()
        for i, pid in enumerate(pids, start=1):
            w.writerow({"slot": i, "sequence": "SR" if i % 2 else "RS", "participant_id": pid,
                        "status": statuses.get(pid, "complete"), "updated": ""})


def test_a_participant_with_fewer_judgments_is_refused_unless_allowed(paper_dir):
    path = _edit(paper_dir, "T03", lambda rows: rows[:10])  # stopped in the first bimodal part
    with open(path, "ab") as f:
        f.write(b"T03,SR,bimodal,1,10,sy")  # and the trial in progress, cut short
    with pytest.raises(ParameterError) as err:
        load_study_data(paper_dir)
    msg = str(err.value)
    assert f"{path}: participant T03 has 1 of 9 judgments in the bimodal block (period 1) " \
           f"(10 of 27 judgments)" in msg
    assert "--allow-incomplete" in msg
    data = read_study(paper_dir, allow_incomplete=True)
    assert data.trials["participant_id"].nunique() == 19 and "T03" not in \
        set(data.trials["participant_id"])
    (i,) = data.incomplete
    assert (i.participant_id, i.judgments, i.file, i.slot_status, i.analysed) == \
        ("T03", 10, str(path), "", False)


def test_allocation_slots_not_marked_complete_are_refused_unless_allowed(paper_dir):
    _allocation(paper_dir, {"T05": "assigned", "T99": "assigned"})  # T99 never judged
    with pytest.raises(ParameterError) as err:
        load_study_data(paper_dir)
    msg = str(err.value)
    assert "participant T05 holds slot 5 of allocation.csv, marked 'assigned', not " \
           "'complete' (27 of 27 judgments)" in msg
    assert "participant T99 holds slot 21 of allocation.csv, marked 'assigned', and has no " \
           "data file (0 of 27 judgments)" in msg
    data = read_study(paper_dir, allow_incomplete=True)
    assert data.trials["participant_id"].nunique() == 20  # T05's 27 judgments are analysed
    assert [(i.participant_id, i.judgments, i.analysed) for i in data.incomplete] == \
        [("T05", 27, True), ("T99", 0, False)]
    _allocation(paper_dir, {})
    assert read_study(paper_dir).incomplete == ()
    _allocation(paper_dir, {"T98": "complete"})  # a data file lost
    with pytest.raises(ParameterError, match=r"participant T98 holds slot 21 of allocation\.csv, "
                                             r"marked 'complete', and has no data file"):
        load_study_data(paper_dir)


def test_analyze_refuses_an_incomplete_study_and_reports_it_when_allowed(paper_dir, tmp_path,
                                                                         capsys):
    from analysis.perception_report import incomplete_sentence
    from talkingface.cli.main import main

    _edit(paper_dir, "T07", lambda rows: rows[:20])
    out = tmp_path / "analysis"
    assert main(["analyze", str(paper_dir), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "participant T07 has 2 of 9 judgments in the bimodal block (period 2) (20 of 27 " \
           "judgments)" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()
    assert main(["analyze", str(paper_dir), "--out", str(out), "--allow-incomplete"]) == 0
    assert "incomplete: T07 (20 of 27 judgments" in capsys.readouterr().out
    summary = json.loads((out / "analysis.json").read_text())
    assert summary["participants"] == 19
    assert [(i["participant_id"], i["judgments"], i["analysed"])
            for i in summary["incomplete"]] == [("T07", 20, False)]
    assert incomplete_sentence(summary) == (
        " The data set is incomplete (analysed with --allow-incomplete): 1 incomplete session "
        "is left out: T07 (20 of 27 judgments).")
    assert incomplete_sentence({"incomplete": []}) == ""


def test_a_study_csv_saved_by_excel_is_read(paper_dir):
    path = paper_dir / "sub-T02" / "sub-T02_task-emotion_beh.csv"
    path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes().replace(b"\n", b"\r\n"))
    df = load_study_data(paper_dir)  # before: "missing columns ['participant_id']"
    assert df["participant_id"].nunique() == 20
    np.testing.assert_array_equal(tallies(df)["VI"].counts, PAPER_TALLIES["VI"])


def test_a_participant_id_with_a_newline_is_refused(paper_dir):
    _edit(paper_dir, "T04", lambda rows: [dict(r, participant_id="T04\n") for r in rows])
    with pytest.raises(ParameterError, match=r"row 2: participant id 'T04\\n' is not allowed"):
        load_study_data(paper_dir)


# --- one contract: what the study writes is what the analysis reads ------------------------
def test_a_session_written_by_the_study_is_read_with_every_contract_column(tmp_path):
    """study.columns is the one definition of the data file: rows appended by the study's
    SessionFile come back from the analysis with every column and value as written."""
    written = {}
    qc = {"n_frames": 90, "frames_late": 0, "frame_interval_ms_mean": 16.7,
          "frame_interval_ms_max": 17.2, "audio_onset_s": 0.004}
    web = {"browser": "Chrome 156", "refresh_hz": 60.02, "stimulus_onset_ms": 1520.5,
           "stimulus_end_ms": 3020.25, "response_onset_ms": 3021.0, "response_ms": 3830.75,
           "fullscreen": True, "focused": False}
    for pid, seq, site in (("P01", "SR", "lab"), ("P02", "RS", "web")):
        trials = session_trials(pid, seq, 5)
        session = SessionFile(tmp_path, pid, trials)
        for t, response in zip(trials, RESPONSES * 7):
            row = trial_row(t, participant_id=pid, sequence=seq, response=response,
                            response_key=response[0], rt_s=0.8, simulated=False,
                            responder_model="human", session=1, site=site,
                            qc=qc if site == "lab" else None, web=web if site == "web" else None,
                            timestamp="2024-05-01T10:00:00+0200")
            session.append(row)
            written[(pid, t.trial_index)] = row
    df = load_study_data(tmp_path)
    assert list(df.columns) == [*COLUMNS, "file", "row"]
    assert len(df) == len(written) == 54
    for _, r in df.iterrows():
        expected = written[(r["participant_id"], r["trial_index"])]
        for c in COLUMNS:
            got = str(r[c]).lower() if c == "simulated" else str(r[c])
            assert got == str(expected[c]), c


def test_analysis_refuses_what_the_contract_does_not_allow(paper_dir):
    """The codes the analysis accepts are study.columns.ALLOWED_CODES, no other list."""
    path = paper_dir / "sub-T01" / "sub-T01_task-emotion_beh.csv"
    for col, allowed in ALLOWED_CODES.items():
        text = path.read_text()
        _edit(paper_dir, "T01", lambda rows, col=col: [dict(rows[0], **{col: "bogus"}),
                                                        *rows[1:]])
        with pytest.raises(ParameterError, match=f"row 2: {col} 'bogus' is not a known code; "
                                                 f"allowed: {', '.join(allowed)}"):
            load_study_data(paper_dir)
        path.write_text(text)


def test_write_study_data_writes_the_studys_format(paper_dir):
    """The tallies' data files are the text study.columns.csv_text makes of their rows."""
    df = load_study_data(paper_dir)
    for pid, rows in df.groupby("participant_id"):
        path = paper_dir / f"sub-{pid}" / f"sub-{pid}_task-emotion_beh.csv"
        records = [{c: str(r[c]).lower() if c == "simulated" else str(r[c]) for c in COLUMNS}
                   for _, r in rows.sort_values("trial_index").iterrows()]
        assert path.read_bytes() == csv_text(records).encode("utf-8")
