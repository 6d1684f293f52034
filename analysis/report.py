"""The PDF report builder (reportlab): headings, paragraphs, real-text tables and figures.

The builder only lays out what it is given; every number comes from a stage's saved results.
Tables are reportlab ``Table`` flowables, so their text is real, searchable PDF text.

Every text the builder takes — titles, headings, paragraphs, captions, notes, table headers and
cells — is reportlab paragraph markup, so a caller passes data through :func:`escape` (``&``,
``<``, ``>``) and writes a literal ampersand as ``&amp;``. reportlab draws the string of a table
cell as it is, without parsing it, so :meth:`Report.table` turns the entities of headers and
cells back into characters; tags (``<b>``) are not supported there.

Every table and figure is cited in the text: a paragraph, caption or note cites a keyed table,
figure or section with ``{label:KEY}`` (its label, "Table 4") or ``{page:KEY}`` (its page),
filled in when the report is laid out, so a citation may come before what it cites.
:meth:`Report.uncited` lists the tables and figures no text cites (the report stage writes them to
``report/uncited.txt``).
"""
from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import escape as _xml_escape
from xml.sax.saxutils import unescape as _xml_unescape

import re

import matplotlib
import numpy as np
from reportlab.lib import colors
from reportlab.lib.pagesizes import A4
from reportlab.lib.styles import ParagraphStyle, getSampleStyleSheet
from reportlab.lib.units import cm
from reportlab.lib.utils import ImageReader
from reportlab.pdfbase import pdfmetrics
from reportlab.pdfbase.ttfonts import TTFont
from reportlab.platypus import (
    Flowable,
    Image,
    KeepTogether,
    PageBreak,
    Paragraph,
    SimpleDocTemplate,
    Spacer,
    Table,
    TableStyle,
)

from groundwork.atomic import atomic_file


def _register_fonts() -> str:
    """DejaVu Sans (shipped inside matplotlib) as the report's font: every character of the
    text, Greek included (ν, Υ, Δ, ±), prints as itself — the PDF's 14 standard fonts have no
    Greek. Returns the family name."""
    root = Path(matplotlib.get_data_path()) / "fonts" / "ttf"
    faces = {"": "DejaVuSans", "-Bold": "DejaVuSans-Bold", "-Oblique": "DejaVuSans-Oblique",
             "-BoldOblique": "DejaVuSans-BoldOblique"}
    for suffix, file in faces.items():
        name = "DejaVuSans" + suffix
        if name not in pdfmetrics.getRegisteredFontNames():
            pdfmetrics.registerFont(TTFont(name, str(root / f"{file}.ttf")))
    pdfmetrics.registerFontFamily("DejaVuSans", normal="DejaVuSans", bold="DejaVuSans-Bold",
                                  italic="DejaVuSans-Oblique",
                                  boldItalic="DejaVuSans-BoldOblique")
    return "DejaVuSans"


FONT = _register_fonts()
BOLD = FONT + "-Bold"
_BASE = getSampleStyleSheet()
_STYLES = {name: ParagraphStyle(f"tf-{name}", parent=_BASE[name],
                                fontName=BOLD if name.startswith(("Heading", "Title")) else
                                FONT + "-Oblique" if name == "Italic" else FONT)
           for name in ("Title", "Heading1", "Heading2", "Heading3", "BodyText", "Italic")}
_STYLES["BodyText"].fontSize = 9.5
_STYLES["BodyText"].leading = 12
_WIDTH = A4[0] - 4 * cm
_ENTITIES = {"&quot;": '"', "&#39;": "'", "&apos;": "'"}  # beyond &amp; &lt; &gt;
MIN_TABLE_PT = 7.0  # no table is set smaller than this
_TAG = re.compile(r"<[^>]+>")
_REF = re.compile(r"\{(page|label):([A-Za-z0-9_.-]+)\}")


def escape(text) -> str:
    """``text`` as markup that prints it verbatim: ``&``, ``<`` and ``>`` escaped."""
    return _xml_escape(str(text))


def _cell(markup) -> str:
    """The characters a table cell's markup stands for (its entities decoded)."""
    return _xml_unescape(str(markup), _ENTITIES)


class _Refs:
    """What a findings page cites: the label of each keyed table, figure or section (known when
    it is added) and its page (known once laid out: ``found`` in this pass, ``pages`` in the
    last)."""

    def __init__(self):
        self.labels: dict = {}
        self.found: dict = {}
        self.pages: dict = {}

    def fill(self, template: str) -> str:
        """``template`` with ``{label:KEY}`` and ``{page:KEY}`` replaced (``?``: not placed)."""
        def sub(m):
            kind, key = m.groups()
            if kind == "label":
                if key not in self.labels:
                    raise KeyError(f"the report cites {key!r}, which it does not have")
                return self.labels[key]
            return str(self.pages.get(key, "?"))
        return _REF.sub(sub, template)


class _Anchor(Flowable):
    """Takes no room; records the page it lands on under ``key``."""

    def __init__(self, refs: _Refs, key: str):
        super().__init__()
        self.refs, self.key = refs, key

    def wrap(self, aw, ah):
        return 0, 0

    def draw(self):
        self.refs.found.setdefault(self.key, self.canv.getPageNumber())


class _Text(Flowable):
    """A paragraph whose ``{label:KEY}`` and ``{page:KEY}`` are filled in when it is laid out
    (every label is known by then; pages from the last layout pass)."""

    def __init__(self, refs: _Refs, text: str, style):
        super().__init__()
        self.refs, self.text, self.style = refs, text, style

    def _paragraph(self) -> Paragraph:
        return Paragraph(self.refs.fill(self.text), self.style)

    def wrap(self, aw, ah):
        self._p = self._paragraph()
        return self._p.wrap(aw, ah)

    def split(self, aw, ah):
        return self._paragraph().split(aw, ah)

    def getSpaceBefore(self):
        return self.style.spaceBefore

    def getSpaceAfter(self):
        return self.style.spaceAfter

    def draw(self):
        self._p.drawOn(self.canv, 0, 0)


class _PageIndex(Flowable):
    """Takes no room; an indexing flowable: ``multiBuild`` lays the document out again until
    every page a ``{page:KEY}`` cites is where the previous pass found it."""

    def __init__(self, refs: _Refs):
        super().__init__()
        self.refs, self._ok = refs, False

    def wrap(self, aw, ah):
        return 0, 0

    def draw(self):
        pass

    def isIndexing(self):
        return True

    def isSatisfied(self):
        return self._ok

    def beforeBuild(self):
        self.refs.found = {}

    def afterBuild(self):
        self._ok = self.refs.found == self.refs.pages
        self.refs.pages = dict(self.refs.found)


class _Findings(Flowable):
    """The findings page: paragraphs whose ``{page:KEY}`` references are filled in from the
    last layout pass (:class:`_PageIndex`)."""

    def __init__(self, refs: _Refs, items: list):
        super().__init__()
        self.refs, self.items = refs, items

    def _table(self) -> Table:
        rows = [[Paragraph(self.refs.fill(t), _STYLES["BodyText"])] for t in self.items]
        t = Table(rows, colWidths=[_WIDTH], hAlign="LEFT")
        t.setStyle(TableStyle([("LEFTPADDING", (0, 0), (-1, -1), 0),
                               ("BOTTOMPADDING", (0, 0), (-1, -1), 4)]))
        return t

    def wrap(self, aw, ah):
        self._t = self._table()
        return self._t.wrap(aw, ah)

    def draw(self):
        self._t.drawOn(self.canv, 0, 0)


class Report:
    """Accumulates flowables; :meth:`build` writes the PDF.

    Sections (:meth:`heading` level 1), tables and figures are numbered as they are added
    ("3.", "Table 4.", "Figure 2."); a table or figure says which pipeline stage made it
    (``stage``, or the stage of the section it is in). A table, figure or section added with a
    ``key`` can be cited by :meth:`findings` with its label and page.
    """

    def __init__(self, title: str, subtitle: str = ""):
        self.title = title
        self.head = [Paragraph(title, _STYLES["Title"])]
        if subtitle:
            self.head.append(Paragraph(subtitle, _STYLES["Italic"]))
        self.head.append(Spacer(1, 0.4 * cm))
        self.story: list = []
        self.refs = _Refs()
        self.counts = {"section": 0, "subsection": 0, "Table": 0, "Figure": 0}
        self._stage = None
        self._findings: list | None = None
        self._texts: list[str] = []  # every text that may cite (paragraphs, captions, notes)
        self._parts: list[tuple] = []  # (label, key or None) of every table and figure

    def _text(self, text: str, style) -> _Text:
        """``text`` as a paragraph whose citations are filled in at layout."""
        self._texts.append(text)
        return _Text(self.refs, text, style)

    def _anchor(self, key: str | None) -> list:
        return [_Anchor(self.refs, key)] if key else []

    def heading(self, text: str, level: int = 1, *, stage: str | None = None,
                key: str | None = None) -> str:
        """A numbered section (level 1: "3.") or subsection (level 2: "3.2"); ``stage``: the
        stage whose results the section shows (its tables' and figures' default). Returns the
        number."""
        if level == 1:
            self.counts["section"] += 1
            self.counts["subsection"] = 0
            number = f"{self.counts['section']}"
            self._stage = stage
        else:
            self.counts["subsection"] += 1
            number = f"{self.counts['section']}.{self.counts['subsection']}"
            if stage is not None:
                self._stage = stage
        label = f"{number}." if level == 1 else number
        if key:
            self.refs.labels[key] = f"section {number}"
        self.story += self._anchor(key) + [Paragraph(f"{label} {text}",
                                                     _STYLES[f"Heading{level}"])]
        return number

    def paragraph(self, text: str) -> None:
        """A paragraph of body text; it may cite parts with ``{label:KEY}``/``{page:KEY}``,
        added before or after it."""
        self.story.append(self._text(text, _STYLES["BodyText"]))

    def _caption(self, kind: str, caption: str, stage: str | None, key: str | None) -> str:
        self.counts[kind] += 1
        label = f"{kind} {self.counts[kind]}"
        if key:
            self.refs.labels[key] = label
        self._parts.append((label, key))
        stage = stage or self._stage
        made = f" <font size=7 color='#555555'>[stage: {stage}]</font>" if stage else ""
        return f"<b>{label}.</b> {caption}{made}"

    def table(self, caption: str, header: list, rows: list, *, note: str = "",
              col_widths: list | None = None, stage: str | None = None,
              key: str | None = None) -> str:
        """A numbered, captioned table; ``rows`` hold markup strings or numbers (formatted by
        the caller). Returns its label ("Table 4").

        reportlab draws a cell's string without parsing it, so the entities are decoded here:
        ``&amp;`` prints as ``&``, as it does in a paragraph. A table too wide for the page is
        set smaller, down to :data:`MIN_TABLE_PT`, then its widest column wraps.
        """
        data = [[_cell(c) for c in header]] + [[_cell(c) for c in r] for r in rows]
        t = self._table(data, col_widths, 8.5)
        markup = any("<" in str(h) for h in header)  # <sub>, <super>: headers as paragraphs
        if col_widths is None and (markup or t.wrap(_WIDTH, A4[1])[0] > _WIDTH):
            t = self._fit(data, [header, *rows])
        caption = self._caption("Table", caption, stage, key)
        parts = self._anchor(key) + [self._text(caption, _STYLES["BodyText"]), t]
        if note:
            parts.append(self._text(f"<font size=7.5>{note}</font>", _STYLES["BodyText"]))
        parts.append(Spacer(1, 0.3 * cm))
        self.story.append(KeepTogether(parts))
        return caption.split(".</b>")[0][3:]

    @classmethod
    def _fit(cls, data: list, markup: list) -> Table:
        """A table too wide for the page, made to fit: its header cells wrap between words,
        then its type shrinks (8.5 pt down to :data:`MIN_TABLE_PT`), then its widest columns are
        capped at one width that makes the table fit and their cells wrap (``markup``: the rows as given)."""
        pad = 3
        for size in np.arange(8.5, MIN_TABLE_PT - 1e-9, -0.25):
            widths = cls._widths(data, size, pad)
            if sum(widths) <= _WIDTH:
                break
        head = ParagraphStyle("head", fontName=BOLD, fontSize=size, leading=1.15 * size)
        data = [[Paragraph(str(c), head) for c in markup[0]]] + [list(r) for r in data[1:]]
        if sum(widths) > _WIDTH:  # the widest columns capped to share what is left, wrapped
            cap = max(widths)
            while sum(min(w, cap) for w in widths) > _WIDTH:
                cap -= 1
            widths = [min(w, cap) for w in widths]
            body = ParagraphStyle("cell", fontName=FONT, fontSize=size, leading=1.2 * size,
                                  splitLongWords=1)
            for i, r in enumerate(markup[1:], 1):
                data[i] = [Paragraph(str(c), body) for c in r]
        return cls._table(data, widths, size, padding=pad)

    @staticmethod
    def _widths(data: list, size: float, pad: float) -> list:
        """Column widths at ``size`` pt: each column's widest body cell, or its header's
        longest word (the header wraps between words), with ``pad`` either side."""
        out = []
        for j in range(len(data[0])):
            body = max((pdfmetrics.stringWidth(str(r[j]), FONT, size) for r in data[1:]),
                       default=0)
            word = max(pdfmetrics.stringWidth(w, BOLD, size) for w in
                       (_TAG.sub("", str(data[0][j])).split() or [""]))
            out.append(max(body, word) + 2 * pad + 1)
        return out

    @staticmethod
    def _table(data: list, col_widths, size: float, padding: float = 6) -> Table:
        t = Table(data, colWidths=col_widths, hAlign="LEFT", repeatRows=1)
        t.setStyle(TableStyle([
            ("FONT", (0, 0), (-1, 0), BOLD, size),
            ("FONT", (0, 1), (-1, -1), FONT, size),
            ("LEFTPADDING", (0, 0), (-1, -1), padding),
            ("RIGHTPADDING", (0, 0), (-1, -1), padding),
            ("LINEABOVE", (0, 0), (-1, 0), 0.8, colors.black),
            ("LINEBELOW", (0, 0), (-1, 0), 0.5, colors.black),
            ("LINEBELOW", (0, -1), (-1, -1), 0.8, colors.black),
            ("ROWBACKGROUNDS", (0, 1), (-1, -1), [colors.white, colors.HexColor("#f3f3f3")]),
            ("VALIGN", (0, 0), (-1, -1), "TOP"),
        ]))
        return t

    def figure(self, path, caption: str, *, width: float = 1.0, stage: str | None = None,
               key: str | None = None) -> str:
        """A numbered PNG scaled to ``width`` × the text width, with its caption underneath.
        Returns its label ("Figure 2")."""
        w, h = ImageReader(str(path)).getSize()
        draw_w = _WIDTH * width
        img = Image(str(path), width=draw_w, height=draw_w * h / w)
        caption = self._caption("Figure", caption, stage, key)
        self.story.append(KeepTogether(self._anchor(key) + [
            img, self._text(f"<font size=8>{caption}</font>", _STYLES["BodyText"]),
            Spacer(1, 0.3 * cm)]))
        return caption.split(".</b>")[0][3:]

    def findings(self, items: list[str], *, title: str = "What this run found") -> None:
        """The first page: ``items`` (paragraph markup), each citing what shows it with
        ``{label:KEY}`` and ``{page:KEY}`` (a table, figure or section added with that key).
        Set it once every cited part has been added."""
        for t in items:
            self.refs.fill(t)  # an unknown key is an error now, not a "?" in the PDF
        self._findings_text = list(items)
        self._findings = [Paragraph(title, _STYLES["Heading1"]), _Findings(self.refs, items),
                          PageBreak()]

    def cited(self) -> set:
        """The keys some text of the report cites (``{label:KEY}`` or ``{page:KEY}``)."""
        texts = self._texts + getattr(self, "_findings_text", [])
        return {key for t in texts for _, key in _REF.findall(t)}

    def uncited(self) -> list[str]:
        """The tables and figures no text cites, as ``"Table 4 (key)"`` (``(no key)``: it
        cannot be cited), in report order; empty when every one is cited."""
        cited = self.cited()
        return [f"{label} ({key or 'no key'})" for label, key in self._parts
                if key is None or key not in cited]

    def build(self, path) -> Path:
        """Write the PDF to ``path``; every citation must name a part the report has (a
        ``KeyError`` names the one it lacks)."""
        for t in self._texts:
            self.refs.fill(t)
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_file(path) as tmp:  # an interrupted build never leaves a short PDF
            self._build(tmp)
        return path

    def _build(self, path: Path) -> None:
        doc = SimpleDocTemplate(str(path), pagesize=A4, leftMargin=2 * cm, rightMargin=2 * cm,
                                topMargin=1.8 * cm, bottomMargin=1.8 * cm, title=self.title,
                                author="talkingface", invariant=1)

        def footer(canvas, doc_):
            canvas.saveState()
            canvas.setFont(FONT, 7.5)
            canvas.drawRightString(A4[0] - 2 * cm, 1.1 * cm, f"{self.title} — page {doc_.page}")
            canvas.restoreState()

        texts = self._texts + getattr(self, "_findings_text", [])
        index = [_PageIndex(self.refs)] if any("{page:" in t for t in texts) else []
        story = index + self.head + (self._findings or []) + self.story
        doc.multiBuild(list(story), onFirstPage=footer, onLaterPages=footer)
