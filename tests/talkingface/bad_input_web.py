"""The bad-input table's part: the web study (``study web``, ``study serve``): stimuli that
are missing or damaged, an output folder that exists, completion settings a recruitment site
cannot take, a folder that is not a built experiment, a port, an observer, a study folder made
with another seed.

``CASES`` are ``(argv, names)`` as in :mod:`tests.talkingface.bad_input_cases`;
:func:`add_inputs` makes the files they name in the suite's working folder.
"""
from __future__ import annotations

import json
from pathlib import Path

from tests.talkingface.bad_input_cases import RUN

STIM = ["--stimuli", "runs/R/stimuli"]


def _web(*args, stim=STIM):
    return ["study", "web", "--out", "web_new", *stim, *args]


def _serve(*args, web="web_fake"):
    return ["study", "serve", "--web", web, "--study-dir", "sd_web_new", *args]


CASES: list = [
    # -- study web: the stimuli are checked before anything is written
    (_web(stim=["--stimuli", "missing_stim"]), ["missing_stim"]),
    (_web(stim=["--stimuli", "stim_sum"]), ["stim_sum", "does not match its checksum"]),
    (_web(stim=["--stimuli", "stim_missing"]), ["stim_missing", "not found"]),
    (_web(stim=["--stimuli", "stim_absent"]), ["stim_absent", "the design needs stimuli"]),
    (["study", "web", "--out", "a_folder", *STIM], ["a_folder", "already exists", "--overwrite"]),
    (_web("--set", "study.completion_code=AB-12"), ["study.completion_code", "AB-12",
                                                    "letters or digits"]),
    (_web("--set", "study.completion_url=http://example.org/done"),
     ["study.completion_url", "http://example.org/done", "https://"]),
    (_web("--set", "study.consent= "), ["study.consent", "not empty"]),
    (["study", "web", *STIM], ["--out"]),
    # -- study serve: a folder that is not a built experiment, its settings, the study folder
    (_serve(web="a_folder"), ["--web a_folder", "no study.json", "talkingface study web"]),
    (_serve(web="web_notjson"), ["web_notjson/study.json", "not JSON"]),
    (_serve(web="web_old"), ["web_old/study.json", "format 7", "allowed: 1"]),
    (_serve("--inject", "oracle"), ["--inject 'oracle'", "allowed: flmp"]),
    (_serve("--port", "70000"), ["--port 70000", "1-65535"]),
    (_serve("--port", "many"), ["--port", "many"]),
    (["study", "serve", "--web", "web_fake", "--study-dir", "runs/R/study_data", *RUN, "--seed",
      "5"], ["allocation.csv was made with seed", "--seed"]),
    (["study", "serve", "--study-dir", "sd_web_new"], ["--web"]),
]


def add_inputs(root: Path) -> None:
    """Make the inputs of :data:`CASES` in ``root``: a folder with a built experiment's
    ``study.json`` only (``web_fake``: serve's checks read nothing else before serving), one
    whose ``study.json`` is not JSON, and one of another format."""
    site = {"format": 1, "keys": {"neutral": "n", "happy": "h", "sad": "s", "not_sure": "u"},
            "practice": True, "manifest_digest": "", "source": ""}
    for name, text in (("web_fake", json.dumps(site)), ("web_notjson", "{ not json"),
                       ("web_old", json.dumps(dict(site, format=7)))):
        (root / name).mkdir()
        (root / name / "study.json").write_text(text)
