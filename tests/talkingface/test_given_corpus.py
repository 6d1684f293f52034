"""A given corpus instead of the synthetic one (``--corpus DIR``, ``corpus.source``): validated
and linked into the run, keyed by its content; a corpus of neutral speech only runs the Motion
Units, the mapping (Tables I–II), the render and the report, skipping the expression parts with
a note; the stages that need the generator are off and the report says why; a run nested in
another folder works the same."""
from __future__ import annotations

import shutil

import pytest
from pypdf import PdfReader

from face_model.corpus import corpus_hash, load_corpus, read_manifest, write_manifest
from face_model.motion_units import MotionUnits
from mapping.checkpoint import AudioMapping
from talkingface.cli.args import resolve_config
from talkingface.cli.main import build_parser, main
from talkingface.config import load_config
from talkingface.paths import RunPaths
from talkingface.stages import read_done, run, stale
from talkingface.stages.applies import expression_note

# the cheapest training that still writes Tables I–II on both splits, scored on the real-speech
# set's first 2 recordings of each speaker and part (21 of 354, every speaker)
QUICK = ["--set", "mlflow.enabled=false", "--set", "mapping.baselines=[]",
         "--set", "mapping.train.max_epochs=20", "--set", "cluster.scheduler=processes",
         "--set", "speech_set.per_speaker=2"]
NEUTRAL_ONLY = "The corpus holds neutral speech only"


def _neutral_copy(src, dst):
    """A copy of the corpus ``src`` at ``dst`` whose manifest lists its neutral rows only."""
    shutil.copytree(src, dst)
    rows = read_manifest(dst / "manifest.csv")
    write_manifest(dst, [r for r in rows if r["expression"] == "neutral"])
    return dst


@pytest.fixture(scope="session")
def neutral_corpus_dir(small_corpus_dir, tmp_path_factory):
    """The small corpus without its smile and sad rows: 4 neutral utterances (read-only)."""
    return _neutral_copy(small_corpus_dir, tmp_path_factory.mktemp("given") / "neutral")


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    return tmp_path


def _config(source, *extra):
    """The quick settings (:data:`QUICK`) with the given corpus ``source``."""
    return load_config(None, [*QUICK[1::2], *extra, f"corpus.source={source}"])


def test_corpus_option_is_the_setting():
    parser = build_parser()
    for command in ("replicate", "train", "ablate"):
        extra = ["--grid", "g.yaml"] if command == "ablate" else []
        args = parser.parse_args([command, "--name", "x", *extra, "--corpus", "my corpus: 1"])
        assert resolve_config(args).corpus.source == "my corpus: 1"  # as typed, not YAML
        args = parser.parse_args([command, "--name", "x", *extra, "--set",
                                  "corpus.source=d"])
        assert resolve_config(args).corpus.source == "d"
    assert load_config(None).corpus.source == ""  # the default: synthesise


def test_train_on_a_given_neutral_corpus(workdir, neutral_corpus_dir, capsys):
    assert main(["train", "--name", "g", "--corpus", str(neutral_corpus_dir), *QUICK]) == 0
    run_dir = workdir / "runs" / "g"
    corpus = read_done(run_dir / "corpus")
    assert corpus["source"] == str(neutral_corpus_dir)
    assert corpus["corpus_hash"] == corpus_hash(neutral_corpus_dir) == corpus_hash(
        run_dir / "corpus")
    assert corpus["expressions"] == ["neutral"] and corpus["n_utterances"] == 4
    assert corpus["linked"] + corpus["copied"] == 2 + 3 * 4  # manifest, corpus.json, files
    assert corpus["key"]["config"] == {"corpus.source": str(neutral_corpus_dir)}  # not synth
    # only the files the manifest lists: the smile and sad files of the folder stay out
    assert sorted(p.name for p in (run_dir / "corpus" / "audio").iterdir()) == sorted(
        f"{r['utt_id']}.wav" for r in read_manifest(neutral_corpus_dir / "manifest.csv"))
    # Motion Units without expression MUs, said so
    units = MotionUnits.load(run_dir / "units" / "motion_units.npz")
    assert units.expressions_ == () and units.n_utterance == 7
    done = read_done(run_dir / "units")
    assert done["expressions"] == [] and done["note"].startswith(NEUTRAL_ONLY)
    assert list(done["summary"]["explained"]) == ["neutral"]
    # the mapping without the expression cascade, with Tables I–II of neutral speech
    mapping = read_done(run_dir / "mapping")
    assert mapping["note"] == done["note"] == expression_note(["neutral"])
    for split, tfmap in mapping["models"].items():
        assert AudioMapping.load(run_dir / "mapping" / tfmap).expressions == ("neutral",)
    parts = {(r["split"], r["expression"], r["part"]) for r in mapping["rows"]
             if r["method"] == "gated_mlp"}
    assert parts == {(s, "neutral", p) for s in ("random_frames", "utterance")
                     for p in ("train", "test")}
    assert (run_dir / "mapping" / "tables.csv").is_file()
    # the keyframes need smile and sad: skipped with a note, not an error
    keyframes = read_done(run_dir / "keyframes")
    assert "smile and sad" in keyframes["skipped"] and not (run_dir / "keyframes" /
                                                            "keyframes.npz").exists()
    assert "utterance split" in capsys.readouterr().out


def test_the_corpus_key_follows_the_given_corpus_content(tmp_path, neutral_corpus_dir):
    source = shutil.copytree(neutral_corpus_dir, tmp_path / "source")
    paths = RunPaths.at(tmp_path / "run")
    cfg = _config(source)
    first = run(["units"], paths, cfg)
    assert stale(["units"], paths, cfg) == []  # the same corpus: reused
    # the synthesis settings do not matter to a given corpus
    assert stale(["units"], paths, _config(source, "synth.marker_noise_px=3")) == []
    # the same corpus in another folder is another source
    moved = shutil.copytree(source, tmp_path / "moved")
    assert stale(["units"], paths, _config(moved)) == ["corpus", "units"]
    # a changed corpus is taken again, with what is downstream of it
    rows = read_manifest(source / "manifest.csv")
    write_manifest(source, rows[:3])
    assert stale(["units"], paths, cfg) == ["corpus", "units"]
    again = run(["units"], paths, cfg)
    assert again["corpus"]["corpus_hash"] != first["corpus"]["corpus_hash"]
    assert again["corpus"]["n_utterances"] == 3
    assert len(read_manifest(paths.corpus / "manifest.csv")) == 3
    # a file written anew under the same name counts too, by its content
    phones = source / rows[0]["phones"]
    original = phones.read_text()
    lines = original.splitlines()
    start, end, phone = lines[-1].split(",")
    _replace(phones, "\n".join([*lines[:-1], f"{start},{float(end) - 0.001:.5f},{phone}"]))
    assert stale(["units"], paths, cfg) == ["corpus", "units"]
    _replace(phones, original)
    assert stale(["units"], paths, cfg) == []  # the same content again: the same key


def _replace(path, text: str) -> None:
    """``path`` as a new file holding ``text`` (as the project's writers replace files)."""
    tmp = path.with_suffix(".tmp")
    tmp.write_text(text)
    tmp.replace(path)


def test_every_file_the_manifest_lists_is_linked_or_copied(tmp_path, neutral_corpus_dir,
                                                           monkeypatch):
    """A corpus from video lists a quality file per utterance: it is taken with the rest, and
    its content joins the key; where a hard link cannot be made, the files are copied."""
    source = shutil.copytree(neutral_corpus_dir, tmp_path / "source")
    rows = read_manifest(source / "manifest.csv")
    (source / "quality").mkdir()
    for r in rows:
        r["quality"] = f"quality/{r['utt_id']}.csv"
        (source / r["quality"]).write_text("frame,confidence,interpolated\n" + "".join(
            f"{k},0.9,0\n" for k in range(int(r["n_frames"]))))
    write_manifest(source, rows)
    paths, cfg = RunPaths.at(tmp_path / "run"), _config(source)
    done = run(["corpus"], paths, cfg)["corpus"]
    assert (done["linked"], done["copied"]) == (2 + 4 * 4, 0)
    taken = load_corpus(paths.corpus)
    assert all(u.quality is not None and u.quality.shape == (u.n_frames, 2)
               for u in taken.utterances)
    one = rows[0]["quality"]
    assert (paths.corpus / one).stat().st_ino == (source / one).stat().st_ino  # a hard link
    _replace(source / one, (source / one).read_text().replace("0.9,0\n", "0.8,1\n", 1))
    assert stale(["corpus"], paths, cfg) == ["corpus"]  # not in corpus_hash, in the key
    # no hard links here (another file system, say): copies
    monkeypatch.setattr("talkingface.stages.given_corpus.os.link", _no_link)
    done = run(["corpus"], paths, cfg)["corpus"]
    assert (done["linked"], done["copied"]) == (0, 2 + 4 * 4)
    assert (paths.corpus / one).stat().st_ino != (source / one).stat().st_ino
    assert (paths.corpus / one).read_text() == (source / one).read_text()
    assert not list(tmp_path.glob("run/.corpus.partial*"))


def _no_link(src, dst):
    raise OSError(18, "Invalid cross-device link", str(src))


def test_a_given_corpus_with_expressions_uses_them(tmp_path, small_corpus_dir):
    paths = RunPaths.at(tmp_path / "run")
    done = run(["keyframes"], paths, _config(small_corpus_dir))
    assert MotionUnits.load(paths.units_model).expressions_ == ("smile", "sad")
    assert "note" not in done["units"] and "note" not in done["corpus"]
    assert "skipped" not in done["keyframes"] and paths.keyframes_model.is_file()


def test_a_run_nested_in_another_folder_trains_on_a_given_neutral_corpus(tmp_path,
                                                                         neutral_corpus_dir):
    outer = RunPaths.create("outer", runs_dir=tmp_path / "runs")
    nested = RunPaths.at(outer.root / "real" / "speaker", cache_dir=outer.cache)
    done = run(["units", "mapping"], nested, _config(neutral_corpus_dir,
                                                     "mapping.splits=[utterance]"))
    assert list(done) == ["corpus", "units", "mapping"]
    assert (nested.root / "units" / "motion_units.npz").is_file()
    assert MotionUnits.load(nested.units_model).expressions_ == ()
    rows = done["mapping"]["rows"]
    assert {r["part"] for r in rows} == {"train", "test"}  # Tables I and II
    assert done["mapping"]["note"].startswith(NEUTRAL_ONLY)
    assert (nested.mapping / "gated_mlp_utterance.tfmap").is_file()
    assert outer.cache.is_dir() and not (outer.root / "real" / "cache").exists()


def test_replicate_on_a_given_neutral_corpus_says_what_it_skips(workdir, neutral_corpus_dir,
                                                                 capsys):
    assert main(["replicate", "--name", "g", "--corpus", str(neutral_corpus_dir), *QUICK,
                 "--set", "mapping.splits=[utterance]", "--set", "mlflow.enabled=true",
                 "--ablations", "none"]) == 0
    run_dir = workdir / "runs" / "g"
    off = ("tracking", "tracked", "voices", "stimuli", "study_data", "analysis", "ceiling")
    for stage in off:
        assert not (run_dir / stage).exists(), stage
    for stage in ("corpus", "units", "keyframes", "mapping", "speech_eval", "render", "report"):
        assert read_done(run_dir / stage) is not None, stage
    report = read_done(run_dir / "report")
    assert set(report["switched_off"]) == set(off)
    assert report["note"] == expression_note(["neutral"])
    render = read_done(run_dir / "render")
    assert render["fig7"] is None and (run_dir / "render" / render["fig6"]).is_file()
    text = " ".join(" ".join(p.extract_text().split())
                    for p in PdfReader(workdir / "reports" / "g.pdf").pages)
    assert "rebuilt on a given corpus" in text and "The given audio-visual corpus" in text
    assert ("The corpus holds neutral speech only: expression Motion Units, the expression "
            "cascade and Tables III–VII (the perception study) are skipped.") in text
    assert "Stages this corpus switches off" in text
    for stage in off:
        assert stage in text
    assert "TABLE I:" in text and "TABLE II:" in text and "TABLE III" not in text
    assert "none (the corpus holds neutral speech only)" in text
    import mlflow

    runs = mlflow.search_runs(experiment_names=["talkingface"], output_format="list")
    top = next(r for r in runs if r.data.tags.get("stage") == "replicate")
    assert top.data.tags["corpus_source"] == str(neutral_corpus_dir)
    assert top.data.metrics["corpus.n_utterances"] == 4
    # the study does not apply to this run: its own command says why, in one line
    capsys.readouterr()
    assert main(["study", "stimuli", "--name", "g", *QUICK, "--set",
                 f"corpus.source={neutral_corpus_dir}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: stage stimuli does not apply") and "\n" not in err


def test_two_corpora_combined_keep_every_row_and_file(tmp_path, neutral_corpus_dir):
    """A synthetic corpus and a real speaker's sentences in one folder (the voices stage's
    ``voices.real_face: added``): every row of both, under the union of their columns, each
    utterance's arrays unchanged; two parts with one utterance id are refused."""
    from tests.talkingface.full_run import real_speaker_part
    from talkingface.stages.given_corpus import combine_corpora
    from groundwork.errors import CorpusError

    real = real_speaker_part(tmp_path / "real", every=40)  # 5 of GRID s1's sentences
    both = combine_corpora([(neutral_corpus_dir, None, "synthetic"), (real, None, "real")],
                           tmp_path / "both")
    parts = [load_corpus(neutral_corpus_dir), load_corpus(real)]
    combined = load_corpus(both)
    want = [u for c in parts for u in c.utterances]
    assert [u.utt_id for u in combined.utterances] == [u.utt_id for u in want]
    for a, b in zip(combined.utterances, want):
        assert (a.markers == b.markers).all() and (a.audio == b.audio).all()
        assert a.phones == b.phones and a.speaker == b.speaker
    assert (both / "real" / "NOTICE.md").is_file()
    # the speakers a model trained on it has heard: each part by its own rule, so the real
    # speaker's recordings in the speech set count as seen
    from analysis.speech_eval import training_speakers

    assert training_speakers(both) == training_speakers(neutral_corpus_dir) | {"grid-s1"}
    assert "grid-s1" not in training_speakers(neutral_corpus_dir)
    # a combined corpus made of a combined one (the voices stage's copy of the training
    # sentences, beside the drawn faces) is read part by part down to the sources
    copy = combine_corpora([(real, None, "")], tmp_path / "copy")
    nested = combine_corpora([(neutral_corpus_dir, None, "synthetic"), (copy, None, "real")],
                             tmp_path / "nested")
    assert training_speakers(copy) == {"grid-s1"}
    assert training_speakers(nested) == training_speakers(both)
    assert [p["folder"] for p in combined.info["parts"]] == ["synthetic", "real"]
    with pytest.raises(CorpusError, match=r"utterance '.+' is in two of the corpora"):
        combine_corpora([(real, None, "a"), (real, None, "b")], tmp_path / "twice")
    assert not (tmp_path / "twice" / "manifest.csv").exists()
