"""The bad-input suite's working folder and its table of cases (used by test_bad_input.py).

The cases run in one folder with a small finished run ``R`` (corpus, units, mapping, stimuli,
study data, report) and a corpus ``c`` (:func:`build_run`: only ``replicate`` and one ``synth``
are computed, once per test run for the whole suite, ``small_run_dir`` in tests/conftest.py),
copied, and beside them the bad inputs the cases name (:func:`add_bad_inputs`): config files,
damaged copies of the corpus, of the study data and of the stimuli, WAV files and model files.
Damaged variants are copies (cheap).

:data:`CASES` are ``(argv, names)``: the command must exit 2 with exactly one line
``error: ...`` on stderr that contains every one of ``names``, and change no file that existed.
:data:`ACCEPTED` are inputs the project promises to take (exit 0).
"""
from __future__ import annotations

import csv
import io
import json
import pickle
import shutil
import subprocess
import zipfile
from pathlib import Path

import imageio_ffmpeg
import numpy as np

from face_model.face_match import MAX_FACE_MISFIT
from groundwork import modelfile
from groundwork.owner import lock_path

TINY = ["--set", "synth.n_sentences=3", "--set", "synth.workers=2", "--set", "mlflow.enabled=false",
        "--set", "real_speaker.corpus=''"]  # the real-speaker stage: test_cli_pipeline
# the real-speech set's first 2 recordings of each speaker and part (21 of 354, all 12 speakers:
# analysis.speech_set.subset_rows) and the tracker's evaluation on 3 utterances (one per
# expression; 6 by default): the speech_eval and tracking stages and their bookkeeping, with less
# work
QUICK = [*TINY, "--set", "mapping.baselines=[linear]", "--set", "mapping.train.max_epochs=20",
         "--set", "tracker.n_utterances=3",
         "--set", "study.n_participants=4", "--set", "voices.grid=none",
         "--set", "ceiling.grid=none", "--set", "speech_set.per_speaker=2", "--ablations", "none"]
RUN = QUICK[:-2]  # the run's settings, for the commands without --ablations

TFMAP = "runs/R/mapping/gated_mlp_utterance.tfmap"  # the run's own model (never damaged)


class Touch:
    """A pickle payload that would create a file when unpickled (a model file must be data)."""

    def __init__(self, path):
        self.path = path

    def __reduce__(self):
        return (Path.touch, (Path(self.path),))


# -- building the folder ---------------------------------------------------------------------
def build_run(root: Path, main) -> Path:
    """Make the run ``R`` and the corpus ``c`` with ``main`` (the CLI entry point) in ``root``
    (the current folder). tests/conftest.py makes this folder once per test run
    (``small_run_dir``); the tests work on copies of it."""
    assert main(["replicate", "--name", "R", *QUICK]) == 0
    assert main(["synth", "--out", "c", *TINY]) == 0
    return root


def _copy(root: Path, src: str, dst: str) -> Path:
    shutil.copytree(root / src, root / dst)
    return root / dst


def _copy_corpus(root: Path, dst: str) -> Path:
    """A copy of corpus ``c`` with its first utterance only (small: the folder is hashed
    before and after every case)."""
    out = root / dst
    out.mkdir()
    shutil.copy(root / "c" / "corpus.json", out)
    with open(root / "c" / "manifest.csv", newline="", encoding="utf-8") as f:
        header, first = list(csv.reader(f))[:2]
    with open(out / "manifest.csv", "w", newline="", encoding="utf-8") as f:
        csv.writer(f, lineterminator="\n").writerows([header, first])
    for col in ("audio", "markers", "phones"):
        rel = first[header.index(col)]
        (out / rel).parent.mkdir(exist_ok=True)
        shutil.copy(root / "c" / rel, out / rel)
    return out


def _rewrite_csv(path: Path, edit) -> None:
    """Apply ``edit(header, rows)`` (lists, edited in place) to a CSV file."""
    with open(path, newline="", encoding="utf-8") as f:
        table = list(csv.reader(f))
    header, rows = table[0], table[1:]
    edit(header, rows)
    with open(path, "w", newline="", encoding="utf-8") as f:
        csv.writer(f, lineterminator="\n").writerows([header, *rows])


def _drop(column: str):
    """An edit for :func:`_rewrite_csv` that removes ``column``."""
    def edit(header, rows):
        i = header.index(column)
        for r in rows:
            del r[i]
        del header[i]
    return edit


def _free_slot(pid: str):
    """An edit of allocation.csv: ``pid``'s slot free again, as before anyone took it."""
    def edit(header, rows):
        for r in rows:
            if r[header.index("participant_id")] == pid:
                r[header.index("participant_id")] = r[header.index("updated")] = ""
                r[header.index("status")] = "free"
    return edit


def _write_wav_raw(path: Path, data: np.ndarray, sr: int, fmt: int) -> None:
    """A WAV file of ``data`` (n_samples, n_channels) as it is, PCM (fmt 1) or float (fmt 3)."""
    n_ch = data.shape[1]
    payload = data.tobytes()
    width = data.dtype.itemsize
    fmt_chunk = (fmt.to_bytes(2, "little") + n_ch.to_bytes(2, "little")
                 + sr.to_bytes(4, "little") + (sr * n_ch * width).to_bytes(4, "little")
                 + (n_ch * width).to_bytes(2, "little") + (8 * width).to_bytes(2, "little"))
    path.write_bytes(b"RIFF" + (4 + 8 + len(fmt_chunk) + 8 + len(payload)).to_bytes(4, "little")
                     + b"WAVE" + b"fmt " + len(fmt_chunk).to_bytes(4, "little") + fmt_chunk
                     + b"data" + len(payload).to_bytes(4, "little") + payload)


def _tfmap_members(path: Path) -> dict:
    with zipfile.ZipFile(path) as z:
        return {i.filename: z.read(i) for i in z.infolist()}


def _tfmap_write(path: Path, members: dict) -> None:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as z:
        for name, data in members.items():
            z.writestr(name, data)


def _npy_bytes(a) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a, allow_pickle=False)
    return buf.getvalue()


def _edit_header(path: Path, edit) -> dict:
    """The members of the model file ``path`` with its JSON record edited by ``edit`` and its
    checksum made to fit again, so that the check after the checksum is the one reached."""
    members = _tfmap_members(path)
    record = json.loads(str(np.load(io.BytesIO(members["metadata.npy"]))[()]))
    edit(record)
    with np.load(path, allow_pickle=False) as z:
        arrays = {n: z[n] for n in z.files if n != "metadata"}
    record.pop("sha256", None)
    record["sha256"] = modelfile.checksum(arrays, record)
    members["metadata.npy"] = _npy_bytes(np.array(json.dumps(record, sort_keys=True)))
    return members


def _damaged_models(models: Path, good: Path, root: Path) -> None:
    """Copies of the model ``good`` damaged inside its .npz: the record's kind, version,
    shapes, method or parameters changed, one array's bytes changed, a pickled member added."""
    _tfmap_write(models / "format.tfmap",
                 _edit_header(good, lambda h: h.__setitem__("kind", "other.thing/1")))
    _tfmap_write(models / "newer.tfmap",
                 _edit_header(good, lambda h: h.__setitem__("version", 9)))

    def wrong_shape(h):
        name = sorted(h["arrays"])[0]
        h["arrays"][name]["shape"] = [7, 7, 7]

    _tfmap_write(models / "shape.tfmap", _edit_header(good, wrong_shape))
    _tfmap_write(models / "method.tfmap",
                 _edit_header(good, lambda h: h.__setitem__("method", "magic")))
    _tfmap_write(models / "params.tfmap",
                 _edit_header(good, lambda h: h.__setitem__("method_params", {})))
    members = _tfmap_members(good)  # one byte of one array changed, the zip itself valid
    name = next(n for n in members if n != "metadata.npy" and len(members[n]) > 200)
    payload = bytearray(members[name])
    payload[-1] ^= 0x01
    members[name] = bytes(payload)
    _tfmap_write(models / "checksum.tfmap", members)
    members = _tfmap_members(good)
    members["mapper/evil.npy"] = pickle.dumps(Touch(str(root / "pwned_member")))
    _tfmap_write(models / "member.tfmap", members)


def add_bad_inputs(root: Path) -> None:
    """The files and folders the cases name, beside ``runs/R`` and ``c``."""
    run = root / "runs" / "R"
    wav = sorted((run / "corpus" / "audio").glob("*.wav"))[0]
    shutil.copy(wav, root / "speech.wav")
    (root / "a_folder").mkdir()
    (root / "notes.txt").write_text("some notes\n")
    # run P: the settings of R (its config only) and a study folder holding a real participant
    people = root / "runs" / "P" / "study_data" / "sub-P01"
    people.mkdir(parents=True)
    shutil.copy(run / "config.yaml", root / "runs" / "P" / "config.yaml")
    (people / "sub-P01_task-emotion_beh.csv").write_text(
        "participant_id,simulated,response\nP01,false,happy\n")
    # -- config files
    (root / "bad.yaml").write_text("synth: [unclosed\n")
    (root / "utf16.yaml").write_bytes("synth:\n  speakers: 2\n".encode("utf-16"))
    (root / "latin1.yaml").write_bytes("synth:\n  voice: caf\xe9\n".encode("latin-1"))
    (root / "list.yaml").write_text("- synth\n")
    (root / "scalar.yaml").write_text("42\n")
    (root / "unknown_key.yaml").write_text("synth:\n  bogus: 1\n")
    (root / "unknown_section.yaml").write_text("nosection:\n  x: 1\n")
    (root / "twice.yaml").write_text("seed: 1\nseed: 2\n")
    (root / "section_scalar.yaml").write_text("synth: 3\n")
    (root / "train_scalar.yaml").write_text("mapping:\n  train: 5\n")
    (root / "bad_epochs.yaml").write_text("mapping:\n  train:\n    max_epochs: -5\n")
    (root / "bad_study.yaml").write_text("study:\n  keys: [n, n, s, u]\n")
    (root / "dir.yaml").mkdir()  # a folder named like a config file (also: an unreadable file)
    (root / "grid.yaml").write_text("children:\n  small:\n    mapping.hidden_max: 20\n")
    (root / "grid_list.yaml").write_text("- a\n- b\n")
    (root / "grid_unknown.yaml").write_text("settings:\n  x:\n    synth.bogus: 1\n")
    (root / "grid_seed.yaml").write_text("children:\n  paper: {}\n  lucky: {seed: 7}\n")
    # -- text for synth
    (root / "empty.txt").write_text("")
    (root / "utf16.txt").write_bytes("One sentence.\n".encode("utf-16"))
    (root / "text_dir.txt").mkdir()
    # -- corpora damaged by hand (copies of c); the first utterance is the damaged one
    first = next(csv.DictReader(open(root / "c" / "manifest.csv", encoding="utf-8")))
    uid = first["utt_id"]
    bad_info = _copy_corpus(root, "bad_info_corpus")
    (bad_info / "corpus.json").write_text("{ damaged")
    (_copy_corpus(root, "info_list_corpus") / "corpus.json").write_text("[1, 2]\n")
    arr = np.load(root / "c" / first["markers"])
    nan = arr.copy()
    nan[3, 5, 0] = np.nan
    np.save(_copy_corpus(root, "nan_corpus") / first["markers"], nan)
    np.save(_copy_corpus(root, "shape_corpus") / first["markers"], arr[:, :40])
    np.save(_copy_corpus(root, "int_corpus") / first["markers"], np.zeros(arr.shape, np.int32))
    np.save(_copy_corpus(root, "obj_corpus") / first["markers"],
            np.array([Touch(str(root / "pwned_npy"))], dtype=object), allow_pickle=True)
    (_copy_corpus(root, "npytext_corpus") / first["markers"]).write_text("not an array\n")
    np.save(_copy_corpus(root, "frames_corpus") / first["markers"], arr[:-5])

    def manifest(name, edit):
        _rewrite_csv(_copy_corpus(root, name) / "manifest.csv", edit)

    manifest("nocol_corpus", _drop("sample_rate"))
    manifest("ghost_corpus", lambda h, rows: rows.insert(0, [
        {"utt_id": "ghost"}.get(k, v).replace(uid, "ghost") for k, v in zip(h, rows[0])]))
    manifest("nframes_corpus", lambda h, rows: rows[0].__setitem__(h.index("n_frames"), "many"))
    manifest("dup_corpus", lambda h, rows: rows.insert(1, list(rows[0])))
    manifest("expr_corpus", lambda h, rows: rows[0].__setitem__(h.index("expression"), "angry"))
    manifest("sr_corpus", lambda h, rows: rows[0].__setitem__(h.index("sample_rate"), "16000"))
    manifest("empty_manifest_corpus", lambda h, rows: rows.clear())

    def phones(name, edit):
        _rewrite_csv(_copy_corpus(root, name) / first["phones"], edit)

    phones("phone_corpus", lambda h, rows: rows[1].__setitem__(2, "zz"))
    phones("order_corpus", lambda h, rows: rows[1].__setitem__(1, "0.001"))  # end < start
    phones("unsorted_corpus", lambda h, rows: rows.__setitem__(slice(1, 3), rows[2:0:-1]))
    phones("phonehdr_corpus", lambda h, rows: h.__setitem__(2, "label"))
    phones("phonenum_corpus", lambda h, rows: rows[1].__setitem__(0, "soon"))
    # audio
    (_copy_corpus(root, "noaudio_corpus") / first["audio"]).unlink()
    (_copy_corpus(root, "badaudio_corpus") / first["audio"]).write_bytes(b"RIFF\x00\x00WAVEjunk")
    y = np.frombuffer((root / "c" / first["audio"]).read_bytes()[44:], "<i2")
    _write_wav_raw(_copy_corpus(root, "short_corpus") / first["audio"], y[:len(y) // 2, None],
                   int(first["sample_rate"]), 1)
    _write_wav_raw(_copy_corpus(root, "stereo_corpus") / first["audio"],
                   np.stack([y, y], axis=1), int(first["sample_rate"]), 1)
    (_copy_corpus(root, "nomanifest_corpus") / "manifest.csv").unlink()
    # a manifest naming a file outside its folder (the reader reads it; a given corpus is
    # linked into a run file by file, inside the run's folder only)
    manifest("outside_corpus", lambda h, rows: rows[0].__setitem__(
        h.index("audio"), f"../c/{rows[0][h.index('audio')]}"))
    # -- WAV files
    (root / "empty.wav").write_bytes(b"")
    (root / "corrupt.wav").write_bytes(b"RIFF\x10\x00\x00\x00WAVEfmt nonsense")
    _write_wav_raw(root / "zero.wav", np.zeros((0, 1), "<i2"), 22050, 1)
    _write_wav_raw(root / "nan.wav", np.full((22050, 1), np.nan, "<f4"), 22050, 3)
    _write_wav_raw(root / "inf.wav", np.r_[np.zeros(100), np.inf][:, None].astype("<f4"),
                   22050, 3)
    (root / "text.wav").write_text("this is not audio\n" * 20)
    shutil.copy(next((run / "stimuli" / "video").glob("*.mp4")), root / "movie.wav")
    (root / "dir.wav").mkdir()
    raw = (root / "speech.wav").read_bytes()
    (root / "truncated.wav").write_bytes(raw[:len(raw) // 2])
    (root / "header_only.wav").write_bytes(raw[:44])
    speech = y.astype(np.float32) / 32768
    _write_wav_raw(root / "rate1.wav", (speech[:200, None] * 32767).astype("<i2"), 1, 1)
    # accepted: stereo, 6 channels, float32, 8 kHz, 24-bit
    _write_wav_raw(root / "stereo.wav", np.stack([y, y], axis=1), 22050, 1)
    _write_wav_raw(root / "six.wav", np.repeat(y[:, None], 6, axis=1), 22050, 1)
    _write_wav_raw(root / "float.wav", speech[:, None].astype("<f4"), 22050, 3)
    _write_wav_raw(root / "pcm8k.wav", (speech[::2, None] * 32767).astype("<i2"), 11025, 1)
    # -- runs with damaged records
    damaged = _copy(root, "runs/R", "runs/D")
    for done in damaged.glob("*/done.json"):
        done.write_text('{"fingerprint": ')
    # every run a command built has its lock file beside it (groundwork.owner): so do these
    for name in ("D", "P"):
        shutil.copy(lock_path(run), lock_path(root / "runs" / name))
    nomodel = root / "runs" / "NOMODEL" / "mapping"  # its models deleted by hand
    nomodel.mkdir(parents=True)
    shutil.copy(run / "mapping" / "done.json", nomodel)
    # -- model files beside the run's own, so that --model reaches the loader (its Motion
    # Units are found next to it)
    models = run / "mapping"
    good = run.parent.parent / TFMAP
    data = good.read_bytes()
    (models / "truncated.tfmap").write_bytes(data[:200])
    # a model of the older, pickled format cut short (it once gave an UnpicklingError)
    (models / "old_truncated.tfmap").write_bytes(
        b'{"format": "talkingface.mapping/2"}\n'
        + pickle.dumps({"weights": list(range(2000))})[:300])
    (models / "empty.tfmap").write_bytes(b"")
    (models / "text.tfmap").write_text("not a model\n")
    (models / "evil.tfmap").write_bytes(
        b'{"format": "talkingface.mapping/2"}\n' + pickle.dumps(Touch(str(root / "pwned"))))
    (models / "dir.tfmap").mkdir()
    flipped = bytearray(data)  # one byte of the file flipped: the zip's CRC disagrees
    flipped[len(flipped) // 2] ^= 0xFF
    (models / "flipped.tfmap").write_bytes(bytes(flipped))
    np.savez(models / "other.npz", a=np.zeros(3), b=np.ones((2, 2)))
    shutil.copy(models / "other.npz", models / "other.tfmap")
    if zipfile.is_zipfile(good):  # (the model format is .npz: damaged from the inside)
        _damaged_models(models, good, root)
    # -- study data damaged by hand (copies of the run's)
    sd = "runs/R/study_data"
    beh = sorted((run / "study_data").glob("sub-*/sub-*_beh.csv"))[0].relative_to(run /
                                                                                   "study_data")

    def study(name, edit):
        _rewrite_csv(_copy(root, sd, name) / beh, edit)

    study("sd_nocol", _drop("response"))
    study("sd_response", lambda h, rows: rows[0].__setitem__(h.index("response"), "angry"))
    study("sd_dup", lambda h, rows: rows.insert(1, list(rows[0])))
    study("sd_short", lambda h, rows: rows.__delitem__(slice(5, None)))
    study("sd_pid", lambda h, rows: rows[0].__setitem__(h.index("participant_id"), "../x"))
    alloc = _copy(root, sd, "sd_alloc")
    (alloc / "allocation.csv").write_text("slot,sequence\n1,XX\n")
    alloc2 = _copy(root, sd, "sd_alloc_cols")
    _rewrite_csv(alloc2 / "allocation.csv", lambda h, rows: rows[0].__setitem__(1, "XX"))
    (_copy(root, sd, "sd_nodesc") / "dataset_description.json").write_text("{ broken")
    bom = _copy(root, sd, "sd_bom")  # accepted: Excel saves CSVs with a UTF-8 byte-order mark
    for f in [*bom.glob("sub-*/sub-*_beh.csv"), bom / "allocation.csv"]:
        f.write_bytes(b"\xef\xbb\xbf" + f.read_bytes())
    (root / "sd_empty").mkdir()
    # -- stimuli damaged by hand (copies of the run's)
    st = "runs/R/stimuli"

    def stimuli(name, edit):
        _rewrite_csv(_copy(root, st, name) / "manifest.csv", edit)

    stimuli("stim_sum", lambda h, rows: rows[1].__setitem__(h.index("sha256_video"), "0" * 64))
    stimuli("stim_nocol", _drop("sha256_wav"))
    stimuli("stim_kind", lambda h, rows: rows[0].__setitem__(h.index("kind"), "smell"))
    stimuli("stim_twice", lambda h, rows: rows.insert(1, list(rows[0])))
    stimuli("stim_absent", lambda h, rows: rows.pop())
    miss = _copy(root, st, "stim_missing")
    next((miss / "video").glob("*.mp4")).unlink()
    changed = _copy(root, st, "stim_changed")
    video = next((changed / "video").glob("*.mp4"))
    video.write_bytes(video.read_bytes()[:-10])
    # -- answers for study run --inject
    (root / "answers_bad.csv").write_text("stimulus_id,response\naudio-normal,maybe\n")
    # -- a simulation cut between two participants: its last one never ran (slot free again)
    cut = _copy(root, sd, "sd_cut")
    last = sorted(cut.glob("sub-SIM*"))[-1]
    shutil.rmtree(last)
    pid = last.name.removeprefix("sub-")
    _rewrite_csv(cut / "allocation.csv", _free_slot(pid))
    # -- outputs that are there already: an analysis folder, the run's study report
    (root / "an_full").mkdir()
    (root / "an_full" / "table_III.csv").write_text("another study's table\n")
    made = root / "reports" / "study" / "study_data_analysis"
    made.mkdir(parents=True)
    (made / "analysis.json").write_text(json.dumps(
        {"study_path": str((root / sd).resolve())}))
    (root / "reports" / "study" / "study_data.pdf").write_bytes(b"%PDF of runs/R/study_data")
    # -- a tracking store that is not a database
    (root / "bad_mlflow.db").write_bytes(b"not a database " * 100)
    add_bad_videos(root)
    for part in PARTS:
        part.add_inputs(root)


GRID = Path(__file__).resolve().parents[1] / "data" / "grid"


def add_bad_videos(root: Path) -> None:
    """Videos ``corpus from-video`` and ``evaluate-face`` must refuse, each in a folder of its
    own with a transcript: no face (a grey picture and a tone), no audio (a GRID clip without
    its sound), a corrupt file, and a GRID clip whose transcript says something else."""
    ffmpeg = imageio_ffmpeg.get_ffmpeg_exe()

    def folder(name: str, text: str = "bin blue by f eight please") -> Path:
        d = root / name
        d.mkdir()
        (d / "clip.txt").write_text(text + "\n")
        return d

    subprocess.run([ffmpeg, "-v", "error", "-f", "lavfi", "-i", "color=c=gray:s=160x120:d=1:r=25",
                    "-f", "lavfi", "-i", "sine=frequency=300:duration=1:sample_rate=44100",
                    "-shortest", "-c:v", "mpeg1video", "-c:a", "mp2",
                    str(folder("v_noface") / "clip.mpg")], check=True)
    subprocess.run([ffmpeg, "-v", "error", "-i", str(GRID / "video" / "bbbf8p.mpg"), "-an",
                    "-c:v", "copy", str(folder("v_noaudio") / "clip.mpg")], check=True)
    (folder("v_corrupt") / "clip.mpg").write_bytes(bytes(range(256)) * 40)
    shutil.copy(GRID / "video" / "bbbf8p.mpg",
                folder("v_mismatch", "place green with q nine again soon") / "clip.mpg")
    shutil.copy(GRID / "video" / "bbbf8p.mpg", folder("v_grid_as_s00"))  # a real face, not s00's


# -- the cases -------------------------------------------------------------------------------
def _animate(*extra, wav="speech.wav", out="o.mp4", model="R"):
    return ["animate", wav, "-o", out, "--model", model, *extra]


def _units(corpus):
    return ["units", "--corpus", corpus, "--out", "u"]


SYNTH = ["synth", "--out", "new1"]
TRAIN = ["train", "--name", "R", *RUN]
SIM = ["study", "simulate", "--n", "4", "--study-dir", "sim_new"]
RUNS = ["study", "run", "--study-dir", "sd_new", "--stimuli", "runs/R/stimuli"]

CASES = [
    # -- corpus from-video and evaluate-face: bad videos, folders and transcripts
    (["corpus", "from-video", "v_noface", "--out", "newv"], ["v_noface/clip.mpg", "no face"]),
    (["corpus", "from-video", "v_noaudio", "--out", "newv"], ["v_noaudio/clip.mpg", "no audio"]),
    (["corpus", "from-video", "v_corrupt", "--out", "newv"], ["v_corrupt/clip.mpg", "video"]),
    (["corpus", "from-video", "v_mismatch", "--out", "newv"],
     ["v_mismatch/clip.mpg", "does not match the audio"]),
    (["corpus", "from-video", "a_folder", "--out", "newv"], ["a_folder", "no videos"]),
    (["corpus", "from-video", "no_such_folder", "--out", "newv"],
     ["no_such_folder", "no such file or folder"]),
    (["corpus", "from-video", "v_mismatch", "--out", "a_folder"],
     ["a_folder", "already exists"]),
    (["corpus", "from-video", "v_mismatch", "--out", "newv", "--workers", "0"],
     ["--workers", "0"]),
    (["evaluate-face", "--model", TFMAP, "a_folder"], ["a_folder", "no videos"]),
    (["evaluate-face", "--model", TFMAP, "v_noface"], ["v_noface/clip.mpg", "no face"]),
    (["evaluate-face", "--model", TFMAP, "--speaker", "s00", "v_grid_as_s00"],
     ["s00", "bbbf8p", "another face", f"{MAX_FACE_MISFIT:.1f} %"]),
    # -- command-line values: wrong type (argparse), out of range, contradictory
    (["synth", "--out", "new1", "--sentences", "abc"], ["--sentences", "abc"]),
    (["synth", "--out", "new1", "--sentences", "-1"], ["-1"]),
    (["synth", "--out", "new1", "--speakers", "two"], ["--speakers", "two"]),
    (["synth", "--out", "new1", "--speakers", "0"], ["synth.speakers", "0"]),
    (["synth", "--out", "new1", "--seed", "abc"], ["--seed", "abc"]),
    (["synth", "--out", "new1", "--seed", "-1"], ["seed", "-1"]),
    (["synth", "--out", "new1", "--seed", str(2**40)], ["seed", str(2**40)]),
    (["synth"], ["--out"]),
    (["units", "--corpus", "c"], ["--out"]),
    (["replicate", "--name", "R", *QUICK, "--workers", "-1"], ["workers", "-1"]),
    (["replicate", "--name", "R", *QUICK, "--workers", "many"], ["--workers", "many"]),
    (["replicate", "--name", "R", *RUN, "--ablations", "missing_grid.yaml"],
     ["missing_grid.yaml"]),
    (["replicate", "--name", "R", *QUICK, "--visual-source", "camera"],
     ["--visual-source", "camera"]),
    (["train", "--name", "R", *RUN, "--visual-source", "camera"], ["camera"]),
    (["ablate", "--grid", "grid.yaml", "--name", "R", *RUN, "--workers", "-2"],
     ["workers", "-2"]),
    (["ablate", "--grid", "none", "--name", "R", *RUN], ["none"]),
    (["ablate", "--grid", "a_folder", "--name", "R", *RUN], ["a_folder"]),
    (["ablate", "--grid", "bad.yaml", "--name", "R", *RUN], ["bad.yaml"]),
    (["ablate", "--grid", "grid_list.yaml", "--name", "R", *RUN], ["grid_list.yaml"]),
    (["ablate", "--grid", "grid_unknown.yaml", "--name", "R", *RUN], ["grid_unknown.yaml"]),
    (["ablate", "--grid", "grid_seed.yaml", "--name", "R", *RUN],
     ["grid_seed.yaml", "'lucky' sets seed 7"]),
    (["report", "--name", "R", "--seed", "x"], ["--seed", "x"]),
    (["report", "--study-data", "runs/R/study_data", "--name", "S", "--seed", "-1"],
     ["seed", "-1"]),
    (["report"], ["--name", "--study-data"]),
    (["report", "--study-data", "runs/R/study_data", "--name", "a b"], ["'a b'"]),
    (["ui", "--port", "http"], ["--port", "http"]),
    (["ui", "--port", "70000", "--set", "mlflow.enabled=false"], ["70000"]),
    (["ui", "--port", "-1"], ["-1"]),
    (["ui", "--set", "mlflow.uri=3"], ["mlflow.uri"]),
    (["ui", "--set", "mlflow.uri=bogus://x"], ["bogus://x", "sqlite://"]),
    (["ui", "--set", "mlflow.uri=sqlite:///bad_mlflow.db"], ["bad_mlflow.db", "not a usable"]),
    (["ui", "--set", "bogus"], ["bogus"]),
    (_animate("--expression", "angry"), ["angry"]),
    (["animate", "speech.wav", "--model", "R"], ["-o"]),
    (["stream", "--fast"], ["WAV file or --mic"]),
    (["stream", "speech.wav", "--mic", "--fast"], ["WAV file or --mic"]),
    (["stream", "speech.wav", "--fast", "--model", "R", "--expression", "angry"], ["angry"]),
    (["stream", "--mic", "--seconds", "-1", "--model", "R"], ["--seconds", "-1"]),
    (["stream", "--mic", "--seconds", "nan", "--model", "R"], ["--seconds", "nan"]),
    (["stream", "--mic", "--seconds", "soon"], ["--seconds", "soon"]),
    (["stream", "speech.wav", "--fast", "--model", "nope"], ["nope"]),
    (["study", "simulate", "--n", "0", "--study-dir", "sim_new"], ["participants", "got 0"]),
    (["study", "simulate", "--n", "-3", "--study-dir", "sim_new"], ["participants", "-3"]),
    (["study", "simulate", "--n", "many"], ["--n", "many"]),
    (["study", "allocate", "--study-dir", "alloc_new", "--n", "0"], ["slots", "got 0"]),
    (["study", "allocate", "--study-dir", "alloc_new", "--n", "-4"], ["slots", "-4"]),
    (["study", "allocate", "--study-dir", "alloc_new", "--n", "x"], ["--n", "x"]),
    (["study", "release", "--study-dir", "runs/R/study_data"], ["--participant"]),
    (["analyze", "runs/R/study_data", "--seed", "-5", "--out", "an_new"], ["seed", "-5"]),
    (["analyze"], ["study_data"]),
    # -- config values, one or more per section (every command reads them the same way)
    ([*SYNTH, "--set", "synth.bogus=1"], ["synth.bogus"]),
    ([*SYNTH, "--set", "nosection.x=1"], ["nosection"]),
    ([*SYNTH, "--set", "synth.speakers=two"], ["synth.speakers", "two"]),
    ([*SYNTH, "--set", "synth.rate_wpm=-100"], ["synth.rate_wpm", "-100"]),
    ([*SYNTH, "--set", "synth.n_sentences=-1"], ["synth.n_sentences", "-1"]),
    ([*SYNTH, "--set", "synth.expressions=[angry]"], ["synth.expressions", "angry"]),
    ([*SYNTH, "--set", "synth.expressions=[]"], ["synth.expressions"]),
    ([*SYNTH, "--set", "synth.backend=festival"], ["synth.backend", "festival"]),
    ([*SYNTH, "--set", "synth.voice=xx-bad"], ["xx-bad"]),
    # --overwrite with a bad value over an existing corpus: refused, the corpus kept
    (["synth", "--out", "c", "--overwrite", *TINY, "--set", "synth.voice=xx-bad"], ["xx-bad"]),
    (["synth", "--out", "c", "--overwrite", *TINY, "--set", "synth.voices=[flite:nobody]"],
     ["flite:nobody"]),
    # a run whose study data holds a real participant is never replaced by --overwrite
    (["replicate", "--name", "P", *QUICK, "--overwrite", "--set", "study.n_participants=5"],
     ["P01", "study_data"]),
    ([*SYNTH, "--set", "synth.workers=-1"], ["synth.workers", "-1"]),
    ([*SYNTH, "--set", "synth.expression_onset_s=[0.5,0.25]"], ["synth.expression_onset_s"]),
    ([*SYNTH, "--set", "synth.expression_intensity=[0.7]"], ["synth.expression_intensity"]),
    ([*SYNTH, "--set", "synth.marker_noise_px=.nan"], ["synth.marker_noise_px", "nan"]),
    ([*SYNTH, "--set", "synth.head_scale=-0.1"], ["synth.head_scale"]),
    ([*SYNTH, "--set", "synth.text_file=nope.txt"], ["nope.txt"]),
    ([*SYNTH, "--set", "synth"], ["synth"]),
    ([*SYNTH, "--set", "synth.speakers=[1"], ["synth.speakers"]),
    ([*SYNTH, "--set", "synth..speakers=2"], ["synth..speakers"]),
    ([*SYNTH, "--set", "synth=3"], ["synth"]),
    ([*SYNTH, "--set", "seed=1.5"], ["seed", "1.5"]),
    (["units", "--corpus", "c", "--out", "u", "--set", "units.n_utterance=0"],
     ["units.n_utterance", "0"]),
    (["units", "--corpus", "c", "--out", "u", "--set", "units.n_expression=-1"],
     ["units.n_expression", "-1"]),
    (["units", "--corpus", "c", "--out", "u", "--set", "units.alignment=magic"],
     ["units.alignment", "magic"]),
    (["units", "--corpus", "c", "--out", "u", "--set", "units.n_utterance=500"],
     ["500"]),
    ([*SYNTH, "--set", "tracker.init=magic"], ["tracker.init", "magic"]),
    ([*SYNTH, "--set", "tracker.n_utterances=0"], ["tracker.n_utterances", "0"]),
    ([*SYNTH, "--set", "tracker.noise_levels=[]"], ["tracker.noise_levels"]),
    ([*SYNTH, "--set", "tracker.noise_levels=[-5]"], ["tracker.noise_levels"]),
    ([*SYNTH, "--set", "tracker.workers=-1"], ["tracker.workers"]),
    ([*TRAIN, "--set", "mapping.method=magic"], ["mapping.method", "magic"]),
    ([*TRAIN, "--set", "mapping.baselines=[magic]"], ["mapping.baselines", "magic"]),
    ([*TRAIN, "--set", "mapping.splits=[]"], ["mapping.splits"]),
    ([*TRAIN, "--set", "mapping.train_fraction=1.5"], ["mapping.train_fraction", "1.5"]),
    ([*TRAIN, "--set", "mapping.n_mfcc=0"], ["mapping.n_mfcc", "0"]),
    ([*TRAIN, "--set", "mapping.context_back=-1"], ["mapping.context_back", "-1"]),
    ([*TRAIN, "--set", "mapping.n_classes=3"], ["mapping.n_classes", "3"]),
    ([*TRAIN, "--set", "mapping.gate_covariance=round"], ["mapping.gate_covariance", "round"]),
    ([*TRAIN, "--set", "mapping.recogniser=whisper"],
     ["mapping.recogniser", "whisper", "pocketsphinx", "hama"]),
    ([*TRAIN, "--set", "mapping.hidden_min=30", "--set", "mapping.hidden_max=20"],
     ["mapping.hidden_min", "mapping.hidden_max"]),
    ([*TRAIN, "--set", "mapping.visual_source=camera"], ["mapping.visual_source", "camera"]),
    ([*TRAIN, "--set", "mapping.deltas=maybe"], ["mapping.deltas", "maybe"]),
    ([*TRAIN, "--set", "mapping.train=5"], ["mapping.train"]),
    ([*TRAIN, "--set", "mapping.train.validation_fraction=1"],
     ["mapping.train.validation_fraction"]),
    ([*TRAIN, "--set", "mapping.train.max_epochs=0"], ["mapping.train.max_epochs", "0"]),
    ([*TRAIN, "--set", "mapping.train.patience=-1"], ["mapping.train.patience", "-1"]),
    ([*TRAIN, "--set", "mapping.train.learning_rate=0"], ["mapping.train.learning_rate"]),
    ([*TRAIN, "--set", "mapping.train.learning_rate=1e-3x"], ["mapping.train.learning_rate"]),
    ([*TRAIN, "--set", "mapping.train.weight_decay=-1"], ["mapping.train.weight_decay"]),
    ([*TRAIN, "--set", "mapping.train.batch_size=-8"], ["mapping.train.batch_size", "-8"]),
    ([*TRAIN, "--set", "mapping.train.bogus=1"], ["mapping.train.bogus"]),
    ([*SIM, "--set", "study.n_participants=0"], ["study.n_participants", "0"]),
    ([*SIM, "--set", "study.keys=[n,n,s,u]"], ["study.keys"]),
    ([*SIM, "--set", "study.keys=[n,h]"], ["study.keys"]),
    ([*SIM, "--set", "study.fixation_s=-1"], ["study.fixation_s", "-1"]),
    ([*SIM, "--set", "study.iti_s=.inf"], ["study.iti_s", "inf"]),
    ([*SIM, "--set", "study.audio_backend=speaker"], ["study.audio_backend", "speaker"]),
    ([*SIM, "--set", "study.practice=3"], ["study.practice", "3"]),
    ([*SYNTH, "--set", "mlflow.enabled=maybe"], ["mlflow.enabled", "maybe"]),
    ([*SYNTH, "--set", "mlflow.experiment=[a]"], ["mlflow.experiment"]),
    ([*SYNTH, "--set", "mlflow.bogus=1"], ["mlflow.bogus"]),
    (["replicate", "--name", "R", *RUN, "--set", "ablations.workers=-1"],
     ["ablations.workers", "-1"]),
    (["replicate", "--name", "R", *RUN, "--set", "ablations.grid=missing_grid.yaml"],
     ["missing_grid.yaml"]),
    # -- config files
    ([*SYNTH, "--config", "bad.yaml"], ["bad.yaml", "line"]),
    ([*SYNTH, "--config", "utf16.yaml"], ["utf16.yaml", "UTF-16"]),
    ([*SYNTH, "--config", "latin1.yaml"], ["latin1.yaml", "UTF-8"]),
    ([*SYNTH, "--config", "list.yaml"], ["list.yaml"]),
    ([*SYNTH, "--config", "scalar.yaml"], ["scalar.yaml"]),
    ([*SYNTH, "--config", "missing.yaml"], ["missing.yaml"]),
    ([*SYNTH, "--config", "dir.yaml"], ["dir.yaml", "folder"]),
    ([*SYNTH, "--config", "unknown_key.yaml"], ["unknown_key.yaml", "synth.bogus"]),
    ([*SYNTH, "--config", "unknown_section.yaml"], ["unknown_section.yaml", "nosection"]),
    ([*SYNTH, "--config", "twice.yaml"], ["twice.yaml", "seed"]),
    ([*SYNTH, "--config", "section_scalar.yaml"], ["section_scalar.yaml", "synth"]),
    ([*TRAIN, "--config", "train_scalar.yaml"], ["train_scalar.yaml", "mapping.train"]),
    ([*TRAIN, "--config", "bad_epochs.yaml"], ["bad_epochs.yaml", "mapping.train.max_epochs"]),
    ([*SIM, "--config", "bad_study.yaml"], ["bad_study.yaml", "study.keys"]),
    (["units", "--corpus", "c", "--out", "u", "--config", "utf16.yaml"], ["utf16.yaml"]),
    (["study", "allocate", "--study-dir", "alloc_new", "--config", "bad.yaml"], ["bad.yaml"]),
    (["study", "stimuli", "--name", "R", "--config", "dir.yaml"], ["dir.yaml"]),
    (["ui", "--config", "bad.yaml"], ["bad.yaml"]),
    (["ui", "--config", "list.yaml"], ["list.yaml"]),
    # -- output folders and files that exist, are files or are folders
    (["synth", "--out", "c", *TINY], ["c", "--overwrite"]),
    (["synth", "--out", "speech.wav", *TINY], ["speech.wav"]),
    (["synth", "--out", "speech.wav/sub", *TINY], ["speech.wav"]),
    (["units", "--corpus", "c", "--out", "runs/R/units"], ["motion_units.npz", "--overwrite"]),
    (["units", "--corpus", "c", "--out", "speech.wav"], ["speech.wav"]),
    (_animate(out="a_folder"), ["a_folder"]),
    (_animate(out="speech.wav"), ["speech.wav", "--overwrite"]),
    (_animate(out="speech.wav/o.mp4"), ["speech.wav"]),
    (_animate("--markers", "speech.wav"), ["speech.wav", "--overwrite"]),
    (_animate("--markers", "a_folder"), ["a_folder"]),
    (_animate("--keyframes", "k.txt"), ["k.txt"]),
    (_animate("--keyframes", "speech.wav"), ["speech.wav"]),
    (_animate("--keyframes", "a_folder/k.json", "--markers", "a_folder"), ["a_folder"]),
    (["analyze", "runs/R/study_data", "--out", "speech.wav"], ["speech.wav"]),
    (["study", "allocate", "--study-dir", "speech.wav"], ["speech.wav"]),
    (["study", "allocate", "--study-dir", "runs/R/study_data", "--n", "8"], ["allocation"]),
    ([*SIM[:-1], "speech.wav"], ["speech.wav"]),
    (["study", "run", "--participant", "P01", "--study-dir", "speech.wav",
      "--stimuli", "runs/R/stimuli"], ["speech.wav"]),
    ([*RUNS, "--participant", "P01", "--screenshot", "a_folder"], ["a_folder"]),
    # -- input files and folders: missing, a file for a folder, a folder for a file
    (["synth", "--out", "new1", "--text", "nope.txt"], ["nope.txt"]),
    (["synth", "--out", "new1", "--text", "text_dir.txt"], ["text_dir.txt"]),
    (["synth", "--out", "new1", "--text", "empty.txt"], ["empty.txt"]),
    (["synth", "--out", "new1", "--text", "utf16.txt"], ["utf16.txt"]),
    (_units("missing"), ["missing"]),
    (_units("speech.wav"), ["speech.wav"]),
    (_units("a_folder"), ["a_folder"]),
    (["ablate", "--grid", "missing.yaml", "--name", "R", *RUN], ["missing.yaml"]),
    (["report", "--name", "never"], ["never"]),
    (["report", "--study-data", "missing_study"], ["missing_study"]),
    (["report", "--study-data", "speech.wav", "--name", "S"], ["speech.wav"]),
    (["analyze", "missing_study"], ["missing_study"]),
    (["analyze", "speech.wav"], ["speech.wav"]),
    (["analyze", "sd_empty"], ["sd_empty"]),
    ([*SIM[:-2], "--study-dir", "sim_new", "--stimuli", "missing_stim"], ["missing_stim"]),
    ([*SIM, "--stimuli", "speech.wav"], ["speech.wav"]),
    ([*SIM, "--stimuli", "a_folder"], ["a_folder"]),
    ([*RUNS, "--participant", "P01", "--inject", "nope.csv"], ["nope.csv"]),
    ([*RUNS, "--participant", "P01", "--inject", "answers_bad.csv"], ["answers_bad.csv"]),
    (["study", "release", "--participant", "P01", "--study-dir", "missing_study"],
     ["missing_study"]),
    # -- run names and study ids
    (["replicate", "--name", "../x"], ["../x"]),
    (["replicate", "--name", ""], ["''"]),
    (["train", "--name", "a b", *RUN], ["'a b'"]),
    (["track", "--name", "R\n", *RUN], ["'R\\n'"]),
    (["ablate", "--grid", "grid.yaml", "--name", "x" * 65, *RUN], ["x" * 65]),
    (["study", "stimuli", "--name", "R\n", *TINY], ["'R\\n'"]),
    (["study", "stimuli", "--name", "Rü", *TINY], ["Rü"]),
    (["report", "--name", ".R"], ["'.R'"]),
    (_animate(model="../R"), ["../R"]),
    ([*RUNS, "--participant", "P03\n"], ["P03"]),
    ([*RUNS, "--participant", "../P03"], ["../P03"]),
    ([*RUNS, "--participant", ""], ["''"]),
    ([*RUNS, "--participant", "P 03"], ["'P 03'"]),
    ([*RUNS, "--participant", "P" * 300], ["P" * 64]),
    ([*RUNS, "--participant", "Pé03"], ["Pé03"]),
    ([*RUNS, "--participant", "P01", "--resume"], ["P01", "--resume"]),
    (["study", "release", "--participant", "NOBODY", "--study-dir", "runs/R/study_data"],
     ["NOBODY"]),
    (["study", "release", "--participant", "SIM01", "--study-dir", "runs/R/study_data"],
     ["SIM01"]),
    (["study", "release", "--participant", "../SIM01", "--study-dir", "runs/R/study_data"],
     ["../SIM01"]),
    # -- runs: a different config is refused before anything is touched
    (["replicate", "--name", "R", *QUICK, "--seed", "5"], ["different config"]),
    (["train", "--name", "R", *RUN, "--seed", "9"], ["different config"]),
    (["track", "--name", "R", *RUN, "--set", "tracker.corpus_noise_sd=-3"],
     ["tracker.corpus_noise_sd"]),
    (["study", "stimuli", "--name", "R", *RUN, "--set", "study.fixation_s=-2"],
     ["study.fixation_s"]),
    # -- corpus files
    (_units("nomanifest_corpus"), ["manifest.csv"]),
    (_units("nocol_corpus"), ["manifest.csv", "sample_rate"]),
    (_units("ghost_corpus"), ["ghost"]),
    (_units("nframes_corpus"), ["manifest.csv", "n_frames"]),
    (_units("dup_corpus"), ["manifest.csv", "duplicate"]),
    (_units("expr_corpus"), ["manifest.csv", "angry"]),
    (_units("sr_corpus"), ["16000"]),
    (_units("empty_manifest_corpus"), ["manifest.csv"]),
    (_units("nan_corpus"), ["NaN"]),
    (_units("shape_corpus"), [".npy", "(75, 40, 2)"]),
    (_units("int_corpus"), [".npy", "int32"]),
    (_units("obj_corpus"), [".npy"]),
    (_units("npytext_corpus"), [".npy"]),
    (_units("frames_corpus"), [".npy", "manifest"]),
    (_units("phone_corpus"), ["zz"]),
    (_units("order_corpus"), [".csv", "line 3"]),
    (_units("unsorted_corpus"), [".csv", "line"]),
    (_units("phonehdr_corpus"), [".csv", "header"]),
    (_units("phonenum_corpus"), [".csv", "soon"]),
    (_units("noaudio_corpus"), [".wav", "not found"]),
    (_units("badaudio_corpus"), [".wav"]),
    (_units("short_corpus"), [".wav", "frames"]),
    (_units("stereo_corpus"), [".wav", "channels"]),
    (_units("bad_info_corpus"), ["corpus.json"]),
    (_units("info_list_corpus"), ["corpus.json"]),
    # -- a given corpus (--corpus DIR, corpus.source): refused before the run is made
    (["train", "--name", "G", *RUN, "--corpus", "missing_corpus"],
     ["corpus.source", "missing_corpus", "not found"]),
    (["train", "--name", "G", *RUN, "--corpus", "speech.wav"], ["speech.wav", "is a file"]),
    (["replicate", "--name", "G", *QUICK, "--corpus", "a_folder"], ["a_folder", "manifest.csv"]),
    (["replicate", "--name", "G", *QUICK, "--corpus", "nan_corpus"], ["nan_corpus", "NaN"]),
    (["ablate", "--grid", "grid.yaml", "--name", "G", *RUN, "--corpus", "shape_corpus"],
     ["shape_corpus", "(75, 40, 2)"]),
    (["train", "--name", "G", *RUN, "--corpus", "outside_corpus"],
     ["outside_corpus", "outside the corpus folder"]),
    (["train", "--name", "G", *RUN, "--set", "corpus.source=phone_corpus"],
     ["phone_corpus", "zz"]),
    (["train", "--name", "G", *RUN, "--corpus", "c", "--visual-source", "tracked"],
     ["mapping.visual_source", "corpus.source"]),
    (["study", "stimuli", "--name", "G", *RUN, "--set", "corpus.source=c"],
     ["stimuli", "does not apply", "corpus.source c"]),
    (["train", "--name", "R", *RUN, "--corpus", "c"], ["different config"]),
    # -- WAV files (speech to animate and to stream)
    (["animate", "missing.wav", "-o", "o.mp4", "--model", "R"], ["missing.wav"]),
    (_animate(wav="empty.wav"), ["empty.wav"]),
    (_animate(wav="corrupt.wav"), ["corrupt.wav"]),
    (_animate(wav="zero.wav"), ["zero.wav", "no samples"]),
    (_animate(wav="nan.wav"), ["nan.wav", "NaN"]),
    (_animate(wav="inf.wav"), ["inf.wav"]),
    (_animate(wav="text.wav"), ["text.wav"]),
    (_animate(wav="movie.wav"), ["movie.wav"]),
    (_animate(wav="dir.wav"), ["dir.wav"]),
    (_animate(wav="truncated.wav"), ["truncated.wav", "truncated"]),
    (_animate(wav="header_only.wav"), ["header_only.wav"]),
    (_animate(wav="rate1.wav"), ["1 Hz", "8000"]),
    (["stream", "missing.wav", "--fast", "--model", "R"], ["missing.wav"]),
    (["stream", "nan.wav", "--fast", "--model", "R"], ["nan.wav"]),
    (["stream", "movie.wav", "--fast", "--model", "R"], ["movie.wav"]),
    (["stream", "dir.wav", "--fast", "--model", "R"], ["dir.wav"]),
    # -- model files
    (_animate(model="nope"), ["nope"]),
    (_animate(model="runs/R/mapping/missing.tfmap"), ["missing.tfmap"]),
    (_animate(model="runs/R/mapping/truncated.tfmap"), ["truncated.tfmap"]),
    (_animate(model="runs/R/mapping/empty.tfmap"), ["empty.tfmap"]),
    (_animate(model="runs/R/mapping/text.tfmap"), ["text.tfmap"]),
    (_animate(model="runs/R/mapping/evil.tfmap"), ["evil.tfmap"]),
    (_animate(model="runs/R/mapping/old_truncated.tfmap"), ["old_truncated.tfmap"]),
    (_animate(model="runs/R/mapping/member.tfmap"), ["member.tfmap"]),
    (_animate(model="runs/R/mapping/dir.tfmap"), ["dir.tfmap"]),
    (_animate(model="runs/R/mapping/format.tfmap"), ["format.tfmap", "other.thing/1"]),
    (_animate(model="runs/R/mapping/newer.tfmap"), ["newer.tfmap", "newer"]),
    (_animate(model="runs/R/mapping/shape.tfmap"), ["shape.tfmap"]),
    (_animate(model="runs/R/mapping/method.tfmap"), ["method.tfmap", "magic"]),
    (_animate(model="runs/R/mapping/params.tfmap"), ["params.tfmap"]),
    (_animate(model="runs/R/mapping/checksum.tfmap"), ["checksum.tfmap", "checksum"]),
    (_animate(model="runs/R/mapping/flipped.tfmap"), ["flipped.tfmap"]),
    (_animate(model="runs/R/mapping/other.tfmap"), ["other.tfmap"]),
    (_animate(model="runs/R/mapping/other.npz"), ["other.npz"]),
    (_animate(model="runs/NOMODEL"), ["NOMODEL"]),
    (_animate(model="a_folder"), ["a_folder"]),
    (["stream", "speech.wav", "--fast", "--model", "runs/R/mapping/checksum.tfmap"],
     ["checksum.tfmap"]),
    # -- study data files
    (["analyze", "sd_nocol", "--out", "an_new"], ["response"]),
    (["analyze", "sd_response", "--out", "an_new"], ["angry"]),
    (["analyze", "sd_dup", "--out", "an_new"], ["trial"]),
    (["analyze", "sd_short", "--out", "an_new"], ["--allow-incomplete"]),
    (["analyze", "sd_pid", "--out", "an_new"], ["../x"]),
    (["report", "--study-data", "sd_response", "--name", "S"], ["angry"]),
    (["study", "release", "--participant", "SIM01", "--study-dir", "sd_alloc"],
     ["allocation.csv"]),
    (["study", "release", "--participant", "SIM01", "--study-dir", "sd_alloc_cols"],
     ["allocation.csv", "line 2", "XX"]),
    ([*RUNS[:-3], "sd_alloc_cols", "--stimuli", "runs/R/stimuli", "--participant", "P09"],
     ["allocation.csv", "XX"]),
    (["study", "allocate", "--study-dir", "sd_alloc", "--n", "4"], ["allocation"]),
    ([*RUNS[:-3], "sd_alloc", "--stimuli", "runs/R/stimuli", "--participant", "P09"],
     ["allocation.csv"]),
    # -- stimuli manifests
    ([*SIM, "--stimuli", "stim_sum"], ["stim_sum", "checksum"]),
    ([*SIM, "--stimuli", "stim_changed"], ["stim_changed", "checksum"]),
    ([*SIM, "--stimuli", "stim_missing"], ["stim_missing", "not found"]),
    ([*SIM, "--stimuli", "stim_nocol"], ["sha256_wav"]),
    ([*SIM, "--stimuli", "stim_kind"], ["smell"]),
    ([*SIM, "--stimuli", "stim_twice"], ["twice"]),
    ([*SIM, "--stimuli", "stim_absent"], ["stim_absent"]),
    ([*RUNS[:-1], "stim_sum", "--participant", "P01"], ["stim_sum", "checksum"]),
    ([*RUNS[:-1], "stim_missing", "--participant", "P01"], ["stim_missing"]),
    # (a file saved with a UTF-8 byte-order mark is read as it is: the session is complete)
    (["study", "run", "--participant", "SIM01", "--study-dir", "sd_bom", "--stimuli",
      "runs/R/stimuli"], ["SIM01", "complete session"]),
    # -- damaged records
    (["report", "--name", "D"], ["done.json"]),
    (_animate(model="D"), ["done.json"]),
    # -- issue 25: writes, outputs, owners and waits
    ([*SYNTH, *TINY, "--set", "synth.marker_noise_px=1e308"],
     ["synth.marker_noise_px", "1e+308", "[0, 50]"]),
    (["analyze", "sd_cut", "--out", "an_new"], ["slot", "study simulate", "--allow-incomplete"]),
    (["analyze", "runs/R/study_data", "--out", "an_full"], ["an_full", "--overwrite"]),
    (["report", "--study-data", "runs/R/study_data"],
     ["reports/study/study_data.pdf", "already exists", "--overwrite"]),
    (["train", "--name", "R", *RUN, "--set", "mlflow.enabled=true", "--set",
      "mlflow.uri=sqlite:///bad_mlflow.db"], ["bad_mlflow.db", "not a usable SQLite database"]),
    (["train", "--name", "R", *RUN, "--set", "mlflow.enabled=true", "--set",
      "mlflow.uri=bogus://x"], ["bogus://x", "sqlite://"]),
    (["train", "--name", "R", *RUN, "--set", "mlflow.enabled=true", "--set",
      "mlflow.uri=file:///tmp/mlruns"], ["file:///tmp/mlruns", "http://"]),
    # -- the cache beside runs/
    (["cache", "clean", "--unused-days", "-1"], ["--unused-days", "-1"]),
    (["cache", "clean", "--unused-days", "nan"], ["--unused-days", "nan"]),
    (["cache", "wipe"], ["wipe", "info", "clean"]),
]

# Inputs the project promises to take: ``(argv, what)``; each must exit 0.
ACCEPTED = [
    (["stream", "stereo.wav", "--fast", "--model", "R"], "a stereo WAV"),
    (["stream", "six.wav", "--fast", "--model", "R"], "six channels (mixed to mono)"),
    (["stream", "float.wav", "--fast", "--model", "R"], "a float32 WAV"),
    (["stream", "pcm8k.wav", "--fast", "--model", "R"], "another sample rate"),
]

# The table's parts kept in modules of their own (each: ``CASES`` and ``add_inputs(root)``); they
# import the shared settings above, so they are imported after them.
from tests.talkingface import (bad_input_faces, bad_input_outputs,  # noqa: E402
                               bad_input_settings, bad_input_web, bad_input_words)

PARTS = (bad_input_faces, bad_input_outputs, bad_input_settings, bad_input_web, bad_input_words)
CASES += [case for part in PARTS for case in part.CASES]
