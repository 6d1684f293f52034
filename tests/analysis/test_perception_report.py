"""`talkingface analyze` and `talkingface report --study-data`: a study's tables, statistics
and model fits from its data alone, here the paper's own tallies turned into trial data."""
import csv
import functools
import json

import numpy as np

from analysis.perception_report import analyze_study
from analysis.study_data import PAPER_TALLIES, trials_from_tallies, write_study_data
from pypdf import PdfReader

from talkingface.cli import study as study_cli
from talkingface.cli.main import main

BOOTSTRAP = 20  # participant resamples of the model fits' intervals (the commands draw 200)


def pdf_text(path) -> str:
    return "\n".join(page.extract_text() for page in PdfReader(path).pages)


def _set_site(data, pid: str, site: str, broke: str | None = None) -> None:
    """Mark a participant's rows as run at ``site``; a web session's rows say they stayed in
    fullscreen and focus, except the first row's ``broke`` column."""
    path = data / f"sub-{pid}" / f"sub-{pid}_task-emotion_beh.csv"
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        fields, rows = reader.fieldnames, list(reader)
    for i, r in enumerate(rows):
        r["site"] = site
        if site == "web":
            r["fullscreen"] = r["focused"] = "true"
            if broke and i == 0:
                r[broke] = "false"
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)


def test_a_study_report_from_data_alone(tmp_path, monkeypatch, capsys):
    """Both commands, run on the data alone, with the fits' bootstrap cut to BOOTSTRAP
    resamples (the same code drawing fewer participant samples; nothing below reads how many):
    the tallies are the data's, the report holds every table, and a replication's report of the
    same name is never replaced."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(study_cli, "analyze_study",
                        functools.partial(analyze_study, bootstrap=BOOTSTRAP))
    data = write_study_data(trials_from_tallies(PAPER_TALLIES, seed=2), tmp_path / "lab_study")
    # five participants ran online (T01 left fullscreen once, T02 lost focus once), five in the
    # lab; the others' judgments are dealt from the tallies (no session: site none)
    for i in range(1, 11):
        _set_site(data, f"T{i:02d}", "web" if i <= 5 else "lab",
                  broke={1: "fullscreen", 2: "focused"}.get(i))
    assert main(["analyze", str(data), "--seed", "1"]) == 0
    out = capsys.readouterr().out
    assert "20 participants (lab 5, none 10, web 5)" in out
    assert "online: 1 left fullscreen and 1 lost focus during a trial" in out
    summary = json.loads((data / "analysis" / "analysis.json").read_text())
    assert summary["sites"] == {"lab": 5, "none": 10, "web": 5, "web_left_fullscreen": 1,
                                "web_lost_focus": 1}
    for name, counts in PAPER_TALLIES.items():
        np.testing.assert_array_equal(summary["tallies"][name]["counts"], counts)
    assert summary["models"]["faces"]["real"]["comparison"]["preferred"] in ("flmp", "wtav")
    replication = tmp_path / "reports" / "lab_study.pdf"  # a run may share the folder's name
    replication.parent.mkdir()
    replication.write_bytes(b"%PDF of a replication")
    assert main(["report", "--study-data", str(data)]) == 0
    assert replication.read_bytes() == b"%PDF of a replication"  # never replaced by surprise
    text = pdf_text(tmp_path / "reports" / "study" / "lab_study.pdf")
    for table in ("TABLE III", "TABLE IV", "TABLE V", "TABLE VI", "TABLE VII"):
        assert f"{table}:" in text
    assert "8 (8)" in text and "5 (5)" in text  # Table VI's confused subjects, ours = paper
    assert "Model comparison" in text and "McNemar" in text and "Hu" in text
    assert "Sessions: 5 in the lab (PsychoPy); 5 online (a browser, study serve); 10 simulated" \
        in " ".join(text.split())
