"""The PDF report builder (reportlab): headings, paragraphs, real-text tables and figures.

The builder only lays out what it is given; every number comes from a stage's saved results.
Tables are reportlab ``Table`` flowables, so their text is real, searchable PDF text.

Every text the builder takes — titles, headings, paragraphs, captions, notes, table headers and
cells — is reportlab paragraph markup, so a caller passes data through :func:`escape` (``&``,
``<``, ``>``) and writes a literal ampersand as ``&amp;``. reportlab draws the string of a table
cell as it is, without parsing it, so :meth:`Report.table` turns the entities of headers and
cells back into characters; tags (``<b>``) are not supported there.
"""
from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import escape as _xml_escape
from xml.sax.saxutils import unescape as _xml_unescape

from reportlab.lib import colors
from reportlab.lib.pagesizes import A4
from reportlab.lib.styles import ParagraphStyle, getSampleStyleSheet
from reportlab.lib.units import cm
from reportlab.lib.utils import ImageReader
from reportlab.platypus import (
    Image,
    KeepTogether,
    PageBreak,
    Paragraph,
    SimpleDocTemplate,
    Spacer,
    Table,
    TableStyle,
)

from face_model.atomic import atomic_file

_STYLES = getSampleStyleSheet()
_WIDTH = A4[0] - 4 * cm
_ENTITIES = {"&quot;": '"', "&#39;": "'", "&apos;": "'"}  # beyond &amp; &lt; &gt;


def escape(text) -> str:
    """``text`` as markup that prints it verbatim: ``&``, ``<`` and ``>`` escaped."""
    return _xml_escape(str(text))


def _cell(markup) -> str:
    """The characters a table cell's markup stands for (its entities decoded)."""
    return _xml_unescape(str(markup), _ENTITIES)


class Report:
    """Accumulates flowables; :meth:`build` writes the PDF."""

    def __init__(self, title: str, subtitle: str = ""):
        self.title = title
        self.story = [Paragraph(title, _STYLES["Title"])]
        if subtitle:
            self.story.append(Paragraph(subtitle, _STYLES["Italic"]))
        self.story.append(Spacer(1, 0.4 * cm))

    def heading(self, text: str, level: int = 1) -> None:
        self.story.append(Paragraph(text, _STYLES[f"Heading{level}"]))

    def paragraph(self, text: str) -> None:
        self.story.append(Paragraph(text, _STYLES["BodyText"]))

    def table(self, caption: str, header: list, rows: list, *, note: str = "",
              col_widths: list | None = None) -> None:
        """A captioned table; ``rows`` hold markup strings or numbers (formatted by the caller).

        reportlab draws a cell's string without parsing it, so the entities are decoded here:
        ``&amp;`` prints as ``&``, as it does in a paragraph.
        """
        data = [[_cell(c) for c in header]] + [[_cell(c) for c in r] for r in rows]
        t = self._table(data, col_widths, 8.5)
        width = t.wrap(_WIDTH, A4[1])[0]
        if width > _WIDTH and col_widths is None:  # too wide for the page: a smaller font
            size = max(5.0, 8.5 * _WIDTH / width - 0.3)
            t = self._table(data, None, size, padding=3)
            if t.wrap(_WIDTH, A4[1])[0] > _WIDTH:  # still too wide: the widest column wraps
                t = self._wrap_widest(t, [header, *rows], data, size)
        parts = [Paragraph(f"<b>{caption}</b>", _STYLES["BodyText"]), t]
        if note:
            parts.append(Paragraph(f"<font size=7.5>{note}</font>", _STYLES["BodyText"]))
        parts.append(Spacer(1, 0.3 * cm))
        self.story.append(KeepTogether(parts))

    @classmethod
    def _wrap_widest(cls, t: Table, markup: list, data: list, size: float) -> Table:
        """``t`` (laid out) again with its widest column narrowed to the width the others
        leave and its cells set as paragraphs that wrap (``markup``: the rows as given)."""
        widths = list(t._colWidths)
        j = max(range(len(widths)), key=widths.__getitem__)
        room = _WIDTH - (sum(widths) - widths[j])
        if room < 2 * cm:  # the other columns fill the page: nothing to wrap into
            return t
        widths[j] = room
        styles = [ParagraphStyle(f"cell{b}", fontName="Helvetica" + b, fontSize=size,
                                 leading=1.2 * size) for b in ("-Bold", "")]
        data = [list(r) for r in data]
        for i, r in enumerate(markup):
            data[i][j] = Paragraph(str(r[j]), styles[min(i, 1)])
        return cls._table(data, widths, size, padding=3)

    @staticmethod
    def _table(data: list, col_widths, size: float, padding: float = 6) -> Table:
        t = Table(data, colWidths=col_widths, hAlign="LEFT", repeatRows=1)
        t.setStyle(TableStyle([
            ("FONT", (0, 0), (-1, 0), "Helvetica-Bold", size),
            ("FONT", (0, 1), (-1, -1), "Helvetica", size),
            ("LEFTPADDING", (0, 0), (-1, -1), padding),
            ("RIGHTPADDING", (0, 0), (-1, -1), padding),
            ("LINEABOVE", (0, 0), (-1, 0), 0.8, colors.black),
            ("LINEBELOW", (0, 0), (-1, 0), 0.5, colors.black),
            ("LINEBELOW", (0, -1), (-1, -1), 0.8, colors.black),
            ("ROWBACKGROUNDS", (0, 1), (-1, -1), [colors.white, colors.HexColor("#f3f3f3")]),
            ("VALIGN", (0, 0), (-1, -1), "TOP"),
        ]))
        return t

    def figure(self, path, caption: str, *, width: float = 1.0) -> None:
        """A PNG scaled to ``width`` × the text width, with its caption underneath."""
        w, h = ImageReader(str(path)).getSize()
        draw_w = _WIDTH * width
        img = Image(str(path), width=draw_w, height=draw_w * h / w)
        self.story.append(KeepTogether([img, Paragraph(f"<font size=8>{caption}</font>",
                                                       _STYLES["BodyText"]),
                                        Spacer(1, 0.3 * cm)]))

    def page_break(self) -> None:
        self.story.append(PageBreak())

    def build(self, path) -> Path:
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
            canvas.setFont("Helvetica", 7.5)
            canvas.drawRightString(A4[0] - 2 * cm, 1.1 * cm, f"{self.title} — page {doc_.page}")
            canvas.restoreState()

        doc.build(list(self.story), onFirstPage=footer, onLaterPages=footer)
