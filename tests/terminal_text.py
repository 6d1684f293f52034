"""What a terminal shows of text written to stderr: tqdm moves the cursor between nested bars
with escape sequences (``ESC [ A`` up a line), and where they fall depends on how many bars the
process holds open (a bar a test before left open moves every later one down a line). Tests
that look for a whole line read it as a terminal shows it."""
import re

_CSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


def screen_lines(text: str) -> list[str]:
    """The lines of ``text`` without terminal escape sequences, each stripped (carriage
    returns split lines too, as a bar's redraw starts one)."""
    return [ln.strip() for ln in _CSI.sub("", text).splitlines()]
