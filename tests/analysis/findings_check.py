"""Reading a built report as a person would: the first page's findings, and whether each
number on it is on the page of the table or figure it cites."""
from __future__ import annotations

import re

from pypdf import PdfReader

CITE = re.compile(r"\((Table|Figure|section) (\d+), p\. (\d+)\)")
NUMBER = re.compile(r"\d+\.\d+")
TITLE = "What this run found"


def page_texts(pdf) -> list[str]:
    """The text of each page, every run of white space as one space."""
    return [" ".join(p.extract_text().split()) for p in PdfReader(pdf).pages]


def findings_of(first_page: str) -> list[str]:
    """The findings on the first page: each a text ending with its last citation."""
    assert TITLE in first_page, first_page[:300]
    body = first_page[first_page.index(TITLE) + len(TITLE):]
    body = body[:body.rindex(" — page 1")] if " — page 1" in body else body
    out, start = [], 0
    for m in CITE.finditer(body):
        rest = body[m.end():]
        if not rest.lstrip(" ;,").startswith("the forest") and (not rest or rest[0] == "."):
            out.append(body[start:m.end() + 1].strip())
            start = m.end() + 1
    return out


def mismatches(pdf) -> list[str]:
    """Every number of a finding that is not on the pages it cites, and every citation whose
    page does not hold the cited table's or figure's caption; empty when all agree."""
    pages = page_texts(pdf)
    bad = []
    items = findings_of(pages[0])
    assert items, "no findings on the first page"
    for item in items:
        cites = CITE.findall(item)
        assert cites, f"a finding without a citation: {item}"
        text = ""
        for kind, n, page in cites:
            p = int(page)
            if not 2 <= p <= len(pages):
                bad.append(f"{kind} {n}: page {p} is not a page of the report")
                continue
            # a table may run over onto the next page: its page and the next are its text
            here = " ".join(pages[p - 1:p + 1])
            if kind != "section" and f"{kind} {n}." not in pages[p - 1]:
                bad.append(f"{kind} {n} is not on page {p}")
            text += " " + here
        stripped = CITE.sub("", item)
        for x in NUMBER.findall(stripped):
            if x not in text:
                bad.append(f"{x} (in: {item[:80]}…) is not on the page it cites")
    return bad
