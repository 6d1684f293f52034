"""The study's trial-data files (DESIGN.md, "Study data"): their columns, the codes a column may
hold, and the text of a file, defined once.

:mod:`study.data` writes them (lab, web and simulated sessions alike); :mod:`analysis.study_data`
reads and validates them. One row per judgment, in the order of :data:`COLUMNS`; UTF-8, ``\\n``
line ends.
"""
from __future__ import annotations

import csv
import io
from pathlib import Path

from study.design import AUDIO, BLOCKS, EXPRESSIONS, FACES, RESPONSES, SEQUENCES

# what a browser measured of a web trial (blank in the lab): times in ms of the page's
# performance.now() clock (the stimulus's first play and its end, the response screen's onset,
# the key press), the browser, the display's measured refresh rate, and whether the page stayed
# in fullscreen and kept the focus from the trial's start to its answer
WEB_COLUMNS = ("browser", "refresh_hz", "stimulus_onset_ms", "stimulus_end_ms",
               "response_onset_ms", "response_ms", "fullscreen", "focused")
# where a session ran: PsychoPy in the lab, a browser, or nowhere (simulated files written
# directly, study.simulate)
SITES = ("lab", "web", "none")
COLUMNS = ("participant_id", "group", "sequence", "block", "period", "trial_index", "face",
           "expression", "audio", "response", "response_key", "rt_s", "stimulus_id",
           "simulated", "responder_model", "session", "n_frames", "frames_late",
           "frame_interval_ms_mean", "frame_interval_ms_max", "audio_onset_s", "timestamp",
           "site", *WEB_COLUMNS)
# what the analysis needs of a data file (the other columns may be missing in older files)
REQUIRED_COLUMNS = ("participant_id", "sequence", "block", "period", "trial_index", "face",
                    "expression", "audio", "response")
# the codes a column may hold ("none": no face, or no sound, in a unimodal trial)
ALLOWED_CODES = {"block": BLOCKS, "face": (*FACES, "none"), "expression": (*EXPRESSIONS, "none"),
                 "audio": (*AUDIO, "none"), "response": RESPONSES, "sequence": SEQUENCES,
                 "site": SITES}
# the (block, period) pairs a row may have, in session order, and the judgments in each
BLOCK_SIZES = {("visual", 0): 6, ("audio", 0): 3, ("bimodal", 1): 9, ("bimodal", 2): 9}


def csv_text(rows, *, header: bool = True, fields=COLUMNS) -> str:
    """Data rows as the text of a data file: the contract's columns in the order of
    :data:`COLUMNS`, ``\\n`` line ends.

    Parameters
    ----------
    rows : iterable of dict
        One judgment each, with every column of the contract (other keys are ignored).
    header : bool
        Start with the header line (a new file); False to append to a file that has one.
    fields : sequence of str
        The columns to write (default :data:`COLUMNS`; a file begun by an older version keeps
        its own header's).

    Returns
    -------
    str
    """
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    if header:
        w.writeheader()
    w.writerows({c: r[c] for c in fields} for r in rows)
    return buf.getvalue()


def read_data_file(path) -> tuple[list[str] | None, list[dict], bool]:
    """The header, the complete rows and whether a cut-short last line was found, of a data
    file (a file saved by Excel starts with a byte-order mark: it is read as UTF-8 all the
    same).

    Parameters
    ----------
    path : path-like
        A ``sub-<id>_task-emotion_beh.csv``.

    Returns
    -------
    fields : list of str or None
        The header's column names (None for an empty file).
    rows : list of dict
        Column → text, one per complete line; a last line without its newline (the trial in
        progress when a session died) is left out.
    torn : bool
        Whether such a line was left out.
    """
    raw = Path(path).read_bytes()
    torn = bool(raw) and not raw.endswith(b"\n")
    if torn:
        raw = raw[:raw.rfind(b"\n") + 1]
    reader = csv.DictReader(io.StringIO(raw.decode("utf-8-sig"), newline=""))
    rows = list(reader)
    return reader.fieldnames, rows, torn
