"""The findings page: page references resolved by laying the report out, numbers checked
against the pages they cite (and the check itself can fail)."""
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
