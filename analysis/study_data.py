"""Reading and validating study data (the contract of DESIGN.md), and the paper's tallies.

:func:`read_study` (and :func:`load_study_data`, its table alone) reads every
``sub-*/sub-*_task-emotion_beh.csv`` of a study folder into one table and refuses, naming the
file and the row: an unknown code (block, face, expression, audio, response, sequence: the
codes of :data:`study.columns.ALLOWED_CODES`), a duplicated trial, a row that contradicts the
design (e.g. a visual-only trial with sound).
Files are read as UTF-8 with or without a byte-order mark (a CSV saved by Excel has one).

An incomplete data set is refused too, naming each participant and their number of judgments:
a participant with fewer than the 27 judgments (a missing block), or whose slot in the
folder's ``allocation.csv`` is not marked complete (a session that was interrupted), or who
holds a slot and has no data file (a session that never wrote a judgment, or a lost file);
and a simulation cut between two participants (its allocation list, one slot per simulated
participant, still has free slots). With ``allow_incomplete=True`` the complete sessions are
analysed and the others are listed (:class:`Incomplete`); a participant with fewer than 27
judgments is left out, one with all 27 is analysed.

:func:`tallies` builds the paper's tables in their exact layout, counts of participants:

* Table III — visual-only: response × (expression × face S/R);
* Table IV — audio-only: response × audio track 1–3;
* Tables V–VII — bimodal, one per audio track: response (with "Not sure") × (expression ×
  face S/R).

:func:`trials_from_tallies` goes the other way (one participant per count), which is how the
analysis is checked against known tables.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from groundwork.errors import ParameterError, first_few
from study.columns import (ALLOWED_CODES, BLOCK_SIZES, COLUMNS, REQUIRED_COLUMNS, csv_text,
                           read_data_file)
from study.data import Allocation, data_path, sidecar_path
from study.design import (AUDIO, EXPRESSIONS, FACES, N_TRIALS, RESPONSES, SEQUENCES,
                          check_participant_id)

FACE_CODE = {"synthetic": "S", "real": "R"}
RESPONSE_LABEL = {"neutral": "Neutral", "happy": "Happy", "sad": "Sad", "not_sure": "Not sure"}
TABLE_OF_AUDIO = {"normal": "V", "good": "VI", "bad": "VII"}
# The paper's tallies (counts of 20 participants), rows neutral, happy, sad, not sure; columns
# (neutral S, neutral R, smile S, smile R, sad S, sad R), or audio tracks 1–3 for Table IV.
PAPER_TALLIES = {
    "III": np.array([[20, 20, 3, 2, 0, 0], [0, 0, 17, 18, 0, 0], [0, 0, 0, 0, 20, 20],
                     [0, 0, 0, 0, 0, 0]]),
    "IV": np.array([[20, 7, 6], [0, 13, 0], [0, 0, 14], [0, 0, 0]]),
    "V": np.array([[20, 20, 4, 2, 1, 0], [0, 0, 16, 18, 0, 0], [0, 0, 0, 0, 19, 20],
                   [0, 0, 0, 0, 0, 0]]),
    "VI": np.array([[16, 17, 2, 0, 0, 0], [4, 3, 18, 20, 0, 0], [0, 0, 0, 0, 12, 15],
                    [0, 0, 0, 0, 8, 5]]),
    "VII": np.array([[13, 14, 14, 13, 0, 0], [0, 0, 2, 4, 0, 0], [7, 6, 0, 0, 20, 20],
                     [0, 0, 4, 3, 0, 0]]),
}


def _fail(path, line, msg):
    raise ParameterError(f"{path}, row {line}: {msg}")


@dataclass(frozen=True)
class Incomplete:
    """A participant whose session is not complete: ``judgments`` of 27 in ``file`` ("" if
    there is none), their allocation slot's status ("" without an allocation list), why, and
    whether their judgments are analysed (all 27 there) or left out."""

    participant_id: str
    judgments: int
    file: str
    slot_status: str
    reason: str
    analysed: bool

    def describe(self) -> str:
        return f"{self.participant_id} ({self.judgments} of {N_TRIALS} judgments; {self.reason})"


@dataclass(frozen=True)
class StudyData:
    """The validated judgments of a study folder (``trials``: one row per judgment, of the
    sessions analysed) and the participants whose session is incomplete."""

    trials: pd.DataFrame
    incomplete: tuple  # of Incomplete


def read_study(study_dir, *, allow_incomplete: bool = False) -> StudyData:
    """All judgments of a study folder, validated, and its incomplete sessions (see the
    module text).

    Parameters
    ----------
    study_dir : path
        A study folder (``study.data`` layout).
    allow_incomplete : bool
        Analyse the complete sessions and list the others, instead of refusing the folder.

    Returns
    -------
    StudyData
        ``trials`` has the contract's columns (``period`` and ``trial_index`` as ints,
        ``simulated`` as bool) plus ``file`` and ``row`` (where each judgment came from);
        ``incomplete`` the sessions that are not complete.

    Raises
    ------
    ParameterError
        No data file; a file lacking a required column (:data:`study.columns.REQUIRED_COLUMNS`);
        a row with an unknown code or that contradicts the design (naming the file and the row);
        a participant in two files; an incomplete session without ``allow_incomplete``; no
        complete session.
    """
    root = Path(study_dir)
    files = sorted(root.glob("sub-*/sub-*_task-emotion_beh.csv"))
    if not files:
        raise ParameterError(f"{root}: no study data (sub-<id>/sub-<id>_task-emotion_beh.csv)")
    slots = _slots(root)
    frames, incomplete, problems = [], [], []
    for path in files:
        fields, rows, _ = read_data_file(path)  # a torn last line: the trial in progress
        missing = [c for c in REQUIRED_COLUMNS if c not in (fields or [])]
        if missing:
            raise ParameterError(f"{path}: missing columns {missing}")
        df, short = _check_participant(path, rows)
        pid = path.parent.name.removeprefix("sub-")
        slot = slots.pop(pid, None)
        status = "" if slot is None else slot["status"]
        if short is None and status in ("", "complete"):
            frames.append(df)
            continue
        reason = short or (f"holds slot {slot['slot']} of allocation.csv, marked {status!r}, "
                           "not 'complete'")
        incomplete.append(Incomplete(pid, len(rows), str(path), status, reason,
                                     analysed=short is None))
        problems.append(f"{path}: participant {pid} {reason} ({len(rows)} of {N_TRIALS} "
                        "judgments)")
        if short is None:
            frames.append(df)
    for pid, slot in sorted(slots.items()):  # a slot taken, and no data file (or a lost one)
        reason = (f"holds slot {slot['slot']} of allocation.csv, marked {slot['status']!r}, "
                  "and has no data file")
        incomplete.append(Incomplete(pid, 0, "", slot["status"], reason, analysed=False))
        problems.append(f"participant {pid} {reason} (0 of {N_TRIALS} judgments)")
    unrun = list(_unrun_simulated(root, frames))  # a simulation cut between participants
    reason = ("planned by the simulation (its allocation.csv has a slot per simulated "
              "participant) and not run: `talkingface study simulate` with the same "
              "settings goes on")
    for slot in unrun:
        incomplete.append(Incomplete(f"slot {slot}", 0, "", "free", reason, analysed=False))
    if unrun:
        who = ("the participant of slot" if len(unrun) == 1 else
               f"the {len(unrun)} participants of slots")
        problems.append(f"{who} {first_few(unrun, sep=', ')} {'was' if len(unrun) == 1 else 'were'} "
                        f"{reason}")
    if incomplete and not allow_incomplete:
        raise ParameterError(
            f"{root} holds incomplete sessions, which are not analysed unless allowed: "
            + first_few(problems) + ". Analyse the complete sessions alone with "
            "`talkingface analyze DIR --allow-incomplete` (allow_incomplete=True), or complete "
            "the sessions first (`talkingface study run --participant ID --resume`)")
    if not frames:
        raise ParameterError(f"{root}: no complete session to analyse (incomplete: "
                             + first_few(i.describe() for i in incomplete) + ")")
    df = pd.concat(frames, ignore_index=True)
    seen: dict[str, str] = {}
    for pid, file in zip(df["participant_id"], df["file"]):
        if seen.setdefault(pid, file) != file:
            raise ParameterError(f"participant {pid} appears in two files: {seen[pid]} and {file}")
    return StudyData(df, tuple(incomplete))


def load_study_data(study_dir, *, allow_incomplete: bool = False) -> pd.DataFrame:
    """The judgments of :func:`read_study` (the complete sessions' only, when
    ``allow_incomplete``)."""
    return read_study(study_dir, allow_incomplete=allow_incomplete).trials


def _unrun_simulated(root: Path, frames: list) -> list:
    """The free slots of a simulation's allocation list: ``study simulate`` makes one slot per
    participant it plans, so a free one is a participant it has not run. A folder is a
    simulation's when every participant's sidecar says so (``simulation_seed``); a real
    study's list has spare slots, and is left alone."""
    alloc = Allocation(root)
    pids = [str(f["participant_id"].iloc[0]) for f in frames if len(f)]
    if not pids or not alloc.path.is_file():
        return []
    for pid in pids:
        try:
            side = json.loads(sidecar_path(root, pid).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return []
        if not isinstance(side, dict) or "simulation_seed" not in side:
            return []
    return [r["slot"] for r in alloc.rows() if r["status"] == "free"]


def _slots(root: Path) -> dict[str, dict]:
    """The allocation list's rows by participant ({} if the folder has no list)."""
    alloc = Allocation(root)
    if not alloc.path.is_file():
        return {}
    return {r["participant_id"]: r for r in alloc.rows() if r.get("participant_id")}


def _check_participant(path: Path, rows: list[dict]) -> tuple[pd.DataFrame, str | None]:
    """The participant's rows, validated, and what is missing ("has 0 of 3 judgments in the
    audio block"; None for a complete session)."""
    if not rows:
        return pd.DataFrame(columns=[*REQUIRED_COLUMNS, "file", "row"]), \
            f"has no judgments in {path.name}"
    pid = rows[0]["participant_id"]
    try:
        check_participant_id(pid)
    except ParameterError as exc:
        _fail(path, 2, str(exc))
    seen_trials: dict[int, int] = {}
    for line, r in enumerate(rows, start=2):
        for col, allowed in ALLOWED_CODES.items():
            if col in r and r[col] not in allowed:  # (site: older files have none)
                _fail(path, line, f"{col} {r[col]!r} is not a known code; allowed: "
                      f"{', '.join(allowed)}")
        if r["participant_id"] != pid:
            _fail(path, line, f"participant {r['participant_id']!r} in the file of {pid!r}")
        try:
            k, period = int(r["trial_index"]), int(r["period"])
        except ValueError:
            _fail(path, line, f"trial_index {r['trial_index']!r} and period {r['period']!r} "
                  "must be integers")
        if k in seen_trials:
            _fail(path, line, f"trial {k} of {pid} duplicated (first at row {seen_trials[k]})")
        seen_trials[k] = line
        if (r["block"], period) not in BLOCK_SIZES:
            _fail(path, line, f"block {r['block']!r} with period {period}; allowed: visual/0, "
                  "audio/0, bimodal/1, bimodal/2")
        face_ok = (r["face"] == "none") == (r["block"] == "audio")
        expr_ok = (r["expression"] == "none") == (r["block"] == "audio")
        audio_ok = (r["audio"] == "none") == (r["block"] == "visual")
        if not (face_ok and expr_ok and audio_ok):
            _fail(path, line, f"a {r['block']} trial with face {r['face']!r}, expression "
                  f"{r['expression']!r}, audio {r['audio']!r} contradicts the design")
        if r["sequence"] != rows[0]["sequence"]:
            _fail(path, line, f"sequence {r['sequence']!r} differs from the participant's "
                  f"{rows[0]['sequence']!r}")
    expected_pid = path.parent.name.removeprefix("sub-")
    if pid != expected_pid:
        _fail(path, 2, f"participant {pid!r} in the folder of {expected_pid!r}")
    seen_stimuli: dict[tuple, int] = {}
    for line, r in enumerate(rows, start=2):
        if not 0 <= int(r["trial_index"]) < N_TRIALS:
            _fail(path, line, f"trial_index {r['trial_index']} outside 0-{N_TRIALS - 1}")
        key = (r["block"], r["face"], r["expression"], r["audio"])
        if key in seen_stimuli:
            _fail(path, line, f"the {r['block']} stimulus face={r['face']} expression="
                  f"{r['expression']} audio={r['audio']} judged twice (first at row "
                  f"{seen_stimuli[key]})")
        seen_stimuli[key] = line
    df = pd.DataFrame(rows)
    df["period"] = df["period"].astype(int)
    df["trial_index"] = df["trial_index"].astype(int)
    counts = df.groupby(["block", "period"]).size().to_dict()
    short = next((f"has {counts.get(bp, 0)} of {n} judgments in the {bp[0]} block"
                  + (f" (period {bp[1]})" if bp[1] else "")
                  for bp, n in BLOCK_SIZES.items() if counts.get(bp, 0) != n), None)
    seq = rows[0]["sequence"]
    first = "synthetic" if seq == "SR" else "real"
    bim = df[df["block"] == "bimodal"]
    wrong = bim[(bim["period"] == 1) != (bim["face"] == first)]
    if len(wrong):
        line = int(wrong.index[0]) + 2
        _fail(path, line, f"sequence {seq} puts the {first} face in bimodal period 1, but this "
              f"row shows the {wrong.iloc[0]['face']} face in period {wrong.iloc[0]['period']}")
    df["simulated"] = df.get("simulated", pd.Series(["false"] * len(df))).astype(str) \
        .str.lower().eq("true")
    df["file"] = str(path)
    df["row"] = np.arange(2, len(df) + 2)
    return df, short


@dataclass(frozen=True)
class Tally:
    """One of the paper's tables: ``counts[response][column]`` with the column labels."""

    name: str
    title: str
    rows: tuple  # response codes
    columns: tuple  # (expression, face code) pairs, or audio codes for Table IV
    counts: np.ndarray  # (len(rows), len(columns)) ints

    def cell(self, response: str, column) -> int:
        return int(self.counts[self.rows.index(response), self.columns.index(column)])

    def column_totals(self) -> np.ndarray:
        return self.counts.sum(0)


def _table(df: pd.DataFrame, name: str, title: str, rows: tuple, columns: list,
           key) -> Tally:
    counts = np.zeros((len(rows), len(columns)), int)
    for _, r in df.iterrows():
        c = key(r)
        counts[rows.index(r["response"]), columns.index(c)] += 1
    return Tally(name, title, rows, tuple(columns), counts)


def tallies(df: pd.DataFrame) -> dict[str, Tally]:
    """The paper's Tables III–VII from validated data.

    Parameters
    ----------
    df : DataFrame
        One row per judgment (:func:`read_study`'s ``trials``, or :func:`trials_from_tallies`).

    Returns
    -------
    dict of str to Tally
        Keys ``III`` … ``VII``; counts of participants, responses × columns.
    """
    face_cols = [(e, FACE_CODE[f]) for e in EXPRESSIONS for f in FACES]
    vis = df[df["block"] == "visual"]
    out = {"III": _table(vis, "III", "Emotion inference based on the animation sequences "
                         "without audio", RESPONSES, face_cols,
                         lambda r: (r["expression"], FACE_CODE[r["face"]])),
           "IV": _table(df[df["block"] == "audio"], "IV", "Emotion inference based on the "
                        "audio", RESPONSES, list(AUDIO), lambda r: r["audio"])}
    for a in AUDIO:
        sub = df[(df["block"] == "bimodal") & (df["audio"] == a)]
        n = TABLE_OF_AUDIO[a]
        out[n] = _table(sub, n, f"Bimodal emotion inference using audio track "
                        f"{AUDIO.index(a) + 1}", RESPONSES, face_cols,
                        lambda r: (r["expression"], FACE_CODE[r["face"]]))
    return out


def trials_from_tallies(tables: dict, *, seed: int = 0) -> pd.DataFrame:
    """Trial-level data that reproduce given Tables III–VII exactly.

    Parameters
    ----------
    tables : dict of str to array-like
        ``tables[name]`` for ``III`` … ``VII``: a response × column count array in the layout
        of :func:`tallies`, shape (4, 6), or (4, 3) for Table IV.
    seed : int
        Seeds the order in which each column's responses are dealt to the participants.

    Returns
    -------
    DataFrame
        27 judgments per participant (``T01`` …), the required contract columns,
        ``simulated`` (True) and ``site`` (``none``).

    Raises
    ------
    ParameterError
        A table missing or of the wrong shape, negative counts, or columns that count
        different numbers of participants.

    Notes
    -----
    Every table column must sum to the same number of participants n. Each column's responses
    are dealt to the n participants in a seeded random order, so the data are one consistent
    set of n complete sessions; sequences alternate SR, RS. Tallies do not say which answers
    came from the same person, so the pairing of a participant's synthetic and real answers is
    one arbitrary choice among many (it changes with ``seed``): paired statistics on such data
    describe that pairing, not the original study's.
    """
    want = {"III": 6, "IV": 3, "V": 6, "VI": 6, "VII": 6}
    for name, ncol in want.items():
        if name not in tables:
            raise ParameterError(f"tables needs {', '.join(want)}; {name} is missing")
        t = np.asarray(tables[name])
        if t.shape != (len(RESPONSES), ncol) or (t < 0).any():
            raise ParameterError(f"table {name} must be {len(RESPONSES)} x {ncol} counts >= 0 "
                                 f"(responses x columns), got shape {t.shape}")
    face_cols = [(e, FACE_CODE[f]) for e in EXPRESSIONS for f in FACES]
    totals = {int(np.asarray(t).sum(0).min()) for t in tables.values()} | \
        {int(np.asarray(t).sum(0).max()) for t in tables.values()}
    if len(totals) != 1:
        raise ParameterError(f"every column of every table must count the same participants; "
                             f"found column totals {sorted(totals)}")
    n = totals.pop()
    rng = np.random.default_rng(seed)

    def column_responses(table, j) -> list[str]:
        resp = [r for r, c in zip(RESPONSES, np.asarray(table)[:, j]) for _ in range(int(c))]
        return [resp[i] for i in rng.permutation(n)]

    by_pid: dict[int, list[dict]] = {i: [] for i in range(n)}
    code_face = {v: k for k, v in FACE_CODE.items()}
    vis = [column_responses(tables["III"], j) for j in range(len(face_cols))]
    aud = [column_responses(tables["IV"], j) for j in range(len(AUDIO))]
    bim = {a: [column_responses(tables[TABLE_OF_AUDIO[a]], j) for j in range(len(face_cols))]
           for a in AUDIO}
    for i in range(n):
        seq = SEQUENCES[i % 2]
        first = "synthetic" if seq == "SR" else "real"
        rows = [("visual", 0, code_face[fc], e, "none", vis[j][i])
                for j, (e, fc) in enumerate(face_cols)]
        rows += [("audio", 0, "none", "none", a, aud[j][i]) for j, a in enumerate(AUDIO)]
        for a in AUDIO:
            for j, (e, fc) in enumerate(face_cols):
                face = code_face[fc]
                rows.append(("bimodal", 1 if face == first else 2, face, e, a, bim[a][j][i]))
        rows.sort(key=lambda r: (list(BLOCK_SIZES).index((r[0], r[1]))))
        for k, (block, period, face, e, a, resp) in enumerate(rows):
            by_pid[i].append({"participant_id": f"T{i + 1:02d}", "sequence": seq,
                              "block": block, "period": period, "trial_index": k, "face": face,
                              "expression": e, "audio": a, "response": resp})
    df = pd.DataFrame([r for rows in by_pid.values() for r in rows])
    df["simulated"] = True
    df["site"] = "none"  # no session ran: the judgments are dealt from published counts
    return df


def write_study_data(df: pd.DataFrame, study_dir) -> Path:
    """Write a DataFrame of judgments as study data files, one per participant, in the format
    the study writes (:func:`study.columns.csv_text`).

    Parameters
    ----------
    df : DataFrame
        One row per judgment (e.g. :func:`trials_from_tallies`); the contract's columns
        (:data:`study.columns.COLUMNS`) it lacks are written blank, booleans as
        ``true``/``false``.
    study_dir : path
        The study folder; ``sub-<id>/sub-<id>_task-emotion_beh.csv`` is written (replaced)
        for every participant.

    Returns
    -------
    pathlib.Path
        ``study_dir``.

    Raises
    ------
    ParameterError
        A participant id that cannot name a data file (:func:`study.design.check_participant_id`).
    """
    root = Path(study_dir)
    for pid, rows in df.groupby("participant_id", sort=True):
        path = data_path(root, str(pid))
        path.parent.mkdir(parents=True, exist_ok=True)
        records = [{c: (str(r[c]).lower() if isinstance(r.get(c), (bool, np.bool_)) else r[c])
                    if c in r else "" for c in COLUMNS}
                   for _, r in rows.sort_values("trial_index").iterrows()]
        with open(path, "w", newline="") as f:
            f.write(csv_text(records))
    return root
