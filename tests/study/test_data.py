"""The study data contract: rows appended and fsync'ed one by one, a torn last row dropped on
resume, complete sessions never reopened, and an allocation list that logs every change."""
import csv
import json
from collections import Counter

import pytest

from groundwork.errors import ParameterError
from study.columns import (
    ALLOWED_CODES,
    BLOCK_SIZES,
    REQUIRED_COLUMNS,
    csv_text,
    read_data_file,
)
from study.data import (
    COLUMNS,
    Allocation,
    SessionFile,
    data_path,
    read_rows,
    trial_row,
    write_atomic,
    write_dataset_description,
)
from study.design import N_TRIALS, RESPONSES, session_trials


def _row(trial, response="neutral"):
    return trial_row(trial, participant_id="P01", sequence="SR", response=response,
                     response_key="n", rt_s=0.5, simulated=False, responder_model="human",
                     session=1, site="lab")


def _write(tmp_path, k):
    trials = session_trials("P01", "SR", 1)
    s = SessionFile(tmp_path, "P01", trials)
    for t in trials[:k]:
        s.append(_row(t))
    return trials, s


def test_rows_go_to_disk_one_by_one_with_the_contract_columns(tmp_path):
    trials, s = _write(tmp_path, 5)
    rows, torn = read_rows(s.path)
    assert not torn and len(rows) == 5 and tuple(rows[0]) == COLUMNS
    assert [int(r["trial_index"]) for r in rows] == [0, 1, 2, 3, 4]
    assert s.path == tmp_path / "sub-P01" / "sub-P01_task-emotion_beh.csv"
    with pytest.raises(ParameterError, match="written out of order"):
        s.append(_row(trials[7]))
    with pytest.raises(ParameterError, match="response 'maybe'; allowed"):
        s.append(_row(trials[5], response="maybe"))


def test_resume_drops_a_torn_row_and_continues_in_order(tmp_path):
    trials, s = _write(tmp_path, 6)
    with open(s.path, "ab") as f:  # a kill in the middle of writing trial 6
        f.write(b"P01,synthetic_first,SR,audio,0,6,no")
    with pytest.raises(ParameterError, match=r"interrupted session \(6 of 27.*--resume"):
        SessionFile(tmp_path, "P01", trials)
    r = SessionFile(tmp_path, "P01", trials, resume=True)
    assert r.dropped_partial and len(r.done) == 6 and r.remaining == trials[6:]
    for t in r.remaining:
        r.append(_row(t))
    rows, torn = read_rows(s.path)
    assert not torn and [int(x["trial_index"]) for x in rows] == list(range(27))
    before = s.path.read_bytes()
    for resume in (False, True):
        with pytest.raises(ParameterError, match="has a complete session.*never overwritten"):
            SessionFile(tmp_path, "P01", trials, resume=resume)
    assert s.path.read_bytes() == before


def test_resume_refuses_a_different_order_and_a_missing_session(tmp_path):
    _write(tmp_path, 3)
    with pytest.raises(ParameterError, match=r"row \d+: .*does not match the planned order"):
        SessionFile(tmp_path, "P01", session_trials("P01", "RS", 99), resume=True)
    with pytest.raises(ParameterError, match="no session to resume"):
        SessionFile(tmp_path, "P02", session_trials("P02", "SR", 1), resume=True)
    assert data_path(tmp_path, "P01").is_file()


def test_allocation_assigns_keeps_releases_and_logs(tmp_path):
    alloc = Allocation(tmp_path)
    rows = alloc.create(8, 5)
    assert [r["status"] for r in rows] == ["free"] * 8
    assert alloc.create(8, 5) == alloc.rows()  # the same list again: kept
    with pytest.raises(ParameterError, match="never replaced"):
        alloc.create(20, 5)
    a = alloc.assign("P01")
    assert alloc.assign("P01") == a  # an aborted participant keeps their slot
    b = alloc.assign("P02")
    assert (a["slot"], b["slot"]) == ("1", "2")
    alloc.set_status("P01", "complete")
    with pytest.raises(ParameterError, match="completed their session"):
        alloc.release("P01")
    freed = alloc.release("P02", note="left early")
    assert freed["status"] == "free" and alloc.assign("P03")["slot"] == "2"
    with open(tmp_path / "allocation_log.csv", newline="") as f:
        events = [(r["event"], r["participant_id"]) for r in csv.DictReader(f)]
    assert events == [("created", ""), ("assigned", "P01"), ("assigned", "P02"),
                      ("complete", "P01"), ("released", "P02"), ("assigned", "P03")]


def test_a_full_list_refuses_a_new_participant(tmp_path):
    alloc = Allocation(tmp_path)
    alloc.create(1, 5)
    alloc.assign("P01")
    with pytest.raises(ParameterError, match="every slot of .* is taken"):
        alloc.assign("P02")
    with pytest.raises(ParameterError, match="no allocation list"):
        Allocation(tmp_path / "elsewhere").assign("P01")


def test_dataset_description_is_psych_ds(tmp_path):
    p = write_dataset_description(tmp_path, name="x", simulated=True)
    d = json.loads(p.read_text())
    assert d["@context"] == "https://schema.org/" and d["@type"] == "Dataset"
    assert d["variableMeasured"] == list(COLUMNS) and "Simulated" in d["description"]


def test_checking_a_data_file_writes_nothing(tmp_path):
    from study.data import check_session_file

    trials, s = _write(tmp_path, 4)
    with open(s.path, "ab") as f:
        f.write(b"P01,synthetic_first,SR,vis")  # torn
    before = s.path.read_bytes()
    rows, torn = check_session_file(tmp_path, "P01", trials, resume=True)
    assert (len(rows), torn) == (4, True) and s.path.read_bytes() == before
    with pytest.raises(ParameterError, match="interrupted session"):
        check_session_file(tmp_path, "P01", trials)
    assert check_session_file(tmp_path, "P02", session_trials("P02", "SR", 1)) == ([], False)
    assert not (tmp_path / "sub-P02").exists()
    with pytest.raises(ParameterError, match=r"participant id 'P01\\n' is not allowed"):
        Allocation(tmp_path).release("P01\n")


def test_the_planned_trials_hold_the_contracts_codes_and_block_sizes():
    """study.columns describes the rows the study writes: every code of every planned trial is
    allowed, and the blocks have the sizes the analysis checks."""
    for pid, seq in (("P01", "SR"), ("P02", "RS")):
        rows = [_row(t, response=r) for t, r in zip(session_trials(pid, seq, 7),
                                                     RESPONSES * 7)]
        for r in rows:
            for col, allowed in ALLOWED_CODES.items():
                assert r[col] in allowed, (col, r[col])
            assert set(REQUIRED_COLUMNS) <= set(COLUMNS) and set(COLUMNS) <= set(r)
        blocks = Counter((r["block"], r["period"]) for r in rows)
        assert dict(blocks) == BLOCK_SIZES and sum(BLOCK_SIZES.values()) == N_TRIALS
        assert list(blocks) == list(BLOCK_SIZES)  # the session order


def test_a_session_file_is_the_text_of_its_rows(tmp_path):
    """Appended one by one or written at once (csv_text), a data file is the same bytes."""
    trials, s = _write(tmp_path, 27)
    fields, rows, torn = read_data_file(s.path)
    assert (fields, torn) == (list(COLUMNS), False) and read_rows(s.path) == (rows, torn)
    assert s.path.read_bytes() == csv_text(rows).encode("utf-8")
    assert csv_text(rows[:1]).splitlines()[0] == ",".join(COLUMNS)
    assert csv_text(rows[1:], header=False) == "".join(
        csv_text([r]).split("\n", 1)[1] for r in rows[1:])


def test_write_atomic_writes_through_a_private_temporary_file(tmp_path):
    path = tmp_path / "new" / "sidecar.json"
    write_atomic(path, '{"a": 1}\n')
    assert path.read_bytes() == b'{"a": 1}\n'
    assert sorted(p.name for p in path.parent.iterdir()) == ["sidecar.json"]
