"""The findings page: page references resolved by laying the report out, numbers checked
against the pages they cite (and the check itself can fail)."""
import json

import pytest

from analysis.report import Report
from tests.analysis.findings_check import findings_of, mismatches, page_texts


def _report(finding_value: str) -> Report:
    rep = Report("T")
    rep.heading("Early", stage="corpus")
    for i in range(60):  # push the cited table two pages on
        rep.paragraph(f"Filler paragraph {i} of the report, long enough to take a line or two "
                      "of the page, so that the table lands on a later page.")
    rep.heading("Results", stage="mapping", key="results")
    rep.table("Figures", ["setting", "R"], [["paper", "0.668 ± 0.011"], ["tdnn", "0.690"]],
              key="t")
    rep.findings([f"<b>Best.</b> tdnn reaches {finding_value} against 0.668 ± 0.011 "
                  "({label:t}, p. {page:t})."])
    return rep


def test_a_finding_cites_the_page_its_table_is_on(tmp_path):
    pdf = _report("0.690").build(tmp_path / "r.pdf")
    pages = page_texts(pdf)
    items = findings_of(pages[0])
    assert len(items) == 1 and "(Table 1, p. " in items[0]
    page = int(items[0].split("p. ")[1].split(")")[0])
    assert page >= 3 and "Table 1. Figures" in pages[page - 1]
    assert "[stage: mapping]" in pages[page - 1]  # the table names the stage that made it
    assert "2. Results" in pages[page - 1] or "2. Results" in pages[page - 2]
    assert mismatches(pdf) == []


def test_a_number_that_is_not_in_the_cited_table_is_caught(tmp_path):
    pdf = _report("0.691").build(tmp_path / "r.pdf")
    assert any(m.startswith("0.691") for m in mismatches(pdf))


def test_citing_a_part_the_report_lacks_is_an_error():
    rep = Report("T")
    with pytest.raises(KeyError, match="'nowhere'"):
        rep.findings(["x ({label:nowhere}, p. {page:nowhere})"])


def _real_face_report(tmp_path, summary: dict):
    """The targets table and the real-speaker section of a made-up summary.json, with the
    real-face finding on the first page."""
    from analysis.config import TargetsConfig
    from analysis.findings import real_speaker_finding
    from analysis.real_face_report import real_speaker_section
    from talkingface.stages.report import targets_section

    stage = tmp_path / "real_speaker"
    stage.mkdir()
    (stage / "summary.json").write_text(json.dumps(summary))
    targets = TargetsConfig()
    rep = Report("T")
    targets_section(rep, targets)
    real_speaker_section(rep, stage, tmp_path, targets=targets)
    item = real_speaker_finding(stage, targets)
    rep.findings([item])
    return item, rep.build(tmp_path / "r.pdf")


def test_the_real_face_finding_says_which_peers_the_default_does_not_beat(tmp_path):
    from tests.analysis.test_real_face_report import _summary

    item, pdf = _real_face_report(tmp_path, _summary(synthetic_r=0.654))
    # 0.654 beats openfacefx and pylipsync but not the loudness envelope (0.701)
    assert "does <b>not</b> beat the loudness envelope (0.701 (0.010) against its " \
           "0.654 (0.010))" in item
    assert "it beats: openfacefx, transcript; openfacefx, loudness; pylipsync" in item
    assert "(1 speaker: no interval)" in item and "not met" in item
    assert "13/20 65 % (30 %)" in item  # the table's closure cell, as it prints it
    assert mismatches(pdf) == []


def test_the_real_face_finding_says_so_when_the_default_beats_every_peer(tmp_path):
    from tests.analysis.test_real_face_report import _summary

    item, pdf = _real_face_report(tmp_path, _summary(synthetic_r=0.757))
    assert "in r it beats the loudness envelope and every peer" in item
    assert "does <b>not</b>" not in item
    assert mismatches(pdf) == []


def _speech_row(model, acc, stream, closed, speakers=4, files=12):
    return {"model": model, "split": "unseen-test", "files": files, "speakers": speakers,
            "speaker_ids": "a;b;c;d", "seconds": 40, "input_rate": "native",
            "viseme_acc": acc, "viseme_acc_lo": acc - 0.05, "viseme_acc_hi": acc + 0.04,
            "chance_viseme_acc": 0.21, "viseme_acc_stream_100ms": stream,
            "viseme_acc_stream_100ms_lo": stream - 0.06,
            "viseme_acc_stream_100ms_hi": stream + 0.03,
            "bilabial_closed_frac": closed, "bilabial_closed_frac_lo": closed - 0.2,
            "bilabial_closed_frac_hi": min(1.0, closed + 0.1),
            "chance_bilabial_closed_frac": 0.33, "bilabial_centre_rel_vowel": 0.5,
            "r_reference": 0.61, "r_reference_lo": 0.5, "r_reference_hi": 0.7,
            "chance_r_reference": 0.02, "silence_rel_vowel": 0.3, "interval_note": ""}


def test_the_speech_finding_compares_streaming_with_streaming_at_the_targets_look_ahead(
        tmp_path):
    from analysis.config import TargetsConfig
    from analysis.findings import speech_finding
    from analysis.speech_report import speech_section
    from talkingface.stages.base import write_csv
    from talkingface.stages.report import targets_section

    speech = tmp_path / "speech_eval"
    speech.mkdir()
    write_csv(speech / "results.csv", [
        _speech_row("voices-one", 0.734, 0.712, 0.6),
        _speech_row("pocketsphinx-5.1.1 allphone", 0.701, 0.655, 0.55),
        _speech_row("hama", 0.745, 0.731, 0.58)])
    targets = TargetsConfig()
    rep = Report("T")
    targets_section(rep, targets)
    speech_section(rep, speech, [], table_ii_R=None, default_model="one", targets=targets)
    item = speech_finding(speech, "one", targets)
    rep.findings([item])
    pdf = rep.build(tmp_path / "r.pdf")
    # the default streaming against the recognisers streaming, with speakers and recordings
    assert "(4 speakers, 12 recordings)" in item and "streaming at 100 ms" in item
    assert "0.71 [0.65, 0.74]" in item and "below the target of 0.8" in item
    assert "pocketsphinx 0.66 [0.59, 0.69] and hama 0.73 [0.67, 0.76]" in item
    assert mismatches(pdf) == []


def test_the_real_face_finding_says_what_drew_the_defaults_faces(tmp_path):
    """A default trained on faces drawn with a fitted articulation is not said to be trained
    on "faces only"; the hand table's default is. The shipped default says what drew it as its
    recorded config does (configs/voices.yaml's model under the paper's config); a model re-saved
    with the fitted articulation in its config is the fitted case."""
    from analysis.findings import drawn_with
    from mapping.checkpoint import AudioMapping
    from talkingface.stages.models import SHIPPED_DIR
    from tests.analysis.test_real_face_report import _summary
    from tests.talkingface.bad_input_ship import tool

    default_synth = tool().expected()[1].synth
    assert drawn_with(SHIPPED_DIR / "gated_mlp_utterance.tfmap") == default_synth.articulation
    assert drawn_with(tmp_path / "none.tfmap") == drawn_with(None) == "table"
    mapping = AudioMapping.load(SHIPPED_DIR / "gated_mlp_utterance.tfmap")
    mapping.metadata["config"]["synth"]["articulation"] = "grid-s1"
    (tmp_path / "fitted").mkdir()
    shipped = tmp_path / "fitted" / "gated_mlp_utterance.tfmap"
    mapping.save(shipped)
    assert drawn_with(shipped) == "grid-s1"
    (tmp_path / "t").mkdir()
    (tmp_path / "f").mkdir()
    table, _ = _real_face_report(tmp_path / "t", _summary(synthetic_r=0.654))
    assert "trained on synthetic speech and faces only" in table
    fitted_summary = {**_summary(synthetic_r=0.654)}
    fitted_summary["models"] = {**(fitted_summary.get("models") or {}),
                                "synthetic_model": str(shipped)}
    fitted, pdf = _real_face_report(tmp_path / "f", fitted_summary)
    assert "trained on synthetic speech and faces drawn with the articulation grid-s1, fitted " \
           "on a real mouth" in fitted
    assert mismatches(pdf) == []
