"""Reading and validating study data (the contract of DESIGN.md), and the paper's tallies.

:func:`load_study_data` reads every ``sub-*/sub-*_task-emotion_beh.csv`` of a study folder into
one table and refuses, naming the file and the row: an unknown code (block, face, expression,
audio, response, sequence), a duplicated trial, a participant missing a block (a session that
is not complete), a row that contradicts the design (e.g. a visual-only trial with sound).

:func:`tallies` builds the paper's tables in their exact layout, counts of participants:

* Table III — visual-only: response × (expression × face S/R);
* Table IV — audio-only: response × audio track 1–3;
* Tables V–VII — bimodal, one per audio track: response (with "Not sure") × (expression ×
  face S/R).

:func:`trials_from_tallies` goes the other way (one participant per count), which is how the
analysis is checked against known tables.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from face_model.errors import ParameterError
from study.data import COLUMNS
from study.design import AUDIO, EXPRESSIONS, FACES, N_TRIALS, RESPONSES, SEQUENCES

FACE_CODE = {"synthetic": "S", "real": "R"}
RESPONSE_LABEL = {"neutral": "Neutral", "happy": "Happy", "sad": "Sad", "not_sure": "Not sure"}
TABLE_OF_AUDIO = {"normal": "V", "good": "VI", "bad": "VII"}
BLOCK_SIZES = {("visual", 0): 6, ("audio", 0): 3, ("bimodal", 1): 9, ("bimodal", 2): 9}
_ALLOWED = {"block": ("visual", "audio", "bimodal"), "face": (*FACES, "none"),
            "expression": (*EXPRESSIONS, "none"), "audio": (*AUDIO, "none"),
            "response": RESPONSES, "sequence": SEQUENCES}
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
REQUIRED = ("participant_id", "sequence", "block", "period", "trial_index", "face",
            "expression", "audio", "response")


def _fail(path, line, msg):
    raise ParameterError(f"{path}, row {line}: {msg}")


def load_study_data(study_dir) -> pd.DataFrame:
    """All judgments of a study folder, validated (see the module text).

    Returns a DataFrame with the contract's columns (``period`` and ``trial_index`` as ints,
    ``simulated`` as bool) plus ``file`` and ``row`` (where each judgment came from).
    """
    root = Path(study_dir)
    files = sorted(root.glob("sub-*/sub-*_task-emotion_beh.csv"))
    if not files:
        raise ParameterError(f"{root}: no study data (sub-<id>/sub-<id>_task-emotion_beh.csv)")
    frames = []
    for path in files:
        with open(path, newline="", encoding="utf-8") as f:
            reader = csv.DictReader(f)
            missing = [c for c in REQUIRED if c not in (reader.fieldnames or [])]
            if missing:
                raise ParameterError(f"{path}: missing columns {missing}")
            rows = list(reader)
        frames.append(_check_participant(path, rows))
    df = pd.concat(frames, ignore_index=True)
    seen: dict[str, str] = {}
    for pid, file in zip(df["participant_id"], df["file"]):
        if seen.setdefault(pid, file) != file:
            raise ParameterError(f"participant {pid} appears in two files: {seen[pid]} and {file}")
    return df


def _check_participant(path: Path, rows: list[dict]) -> pd.DataFrame:
    if not rows:
        raise ParameterError(f"{path}: no judgments")
    pid = rows[0]["participant_id"]
    seen_trials: dict[int, int] = {}
    for line, r in enumerate(rows, start=2):
        for col, allowed in _ALLOWED.items():
            if r[col] not in allowed:
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
    for (block, period), n in BLOCK_SIZES.items():
        if counts.get((block, period), 0) != n:
            raise ParameterError(
                f"{path}: participant {pid} has {counts.get((block, period), 0)} of {n} "
                f"judgments in the {block} block" + (f" (period {period})" if period else "")
                + f"; an incomplete session ({len(df)} of {N_TRIALS}) cannot be analysed")
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
    return df


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
    """Tables III–VII (keys ``III`` … ``VII``) from validated data."""
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
    """Trial-level data that reproduce given Tables III–VII exactly (``tables[name]`` a
    response × column count array in the layout of :func:`tallies`).

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
    return df


def write_study_data(df: pd.DataFrame, study_dir) -> Path:
    """Write a DataFrame of judgments as study data files (the contract's columns; missing ones
    blank), one per participant."""
    root = Path(study_dir)
    for pid, rows in df.groupby("participant_id", sort=True):
        sub = root / f"sub-{pid}"
        sub.mkdir(parents=True, exist_ok=True)
        with open(sub / f"sub-{pid}_task-emotion_beh.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=COLUMNS, lineterminator="\n")
            w.writeheader()
            for _, r in rows.sort_values("trial_index").iterrows():
                w.writerow({c: (str(r[c]).lower() if isinstance(r.get(c), (bool, np.bool_))
                                else r[c]) if c in r else "" for c in COLUMNS})
    return root
