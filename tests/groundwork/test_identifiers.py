"""One rule for every identifier that becomes a file or folder name: the whole value matches
(``re.fullmatch``), so a trailing newline — which ``re.match`` with ``$`` lets through — never
names a folder, a report or a data row."""
import re

import pytest

from groundwork.errors import ParameterError
from groundwork.identifiers import check_identifier
from study.design import check_participant_id, check_stimulus_id
from talkingface.paths import RunPaths, check_run_name


def test_the_whole_value_must_match():
    assert check_identifier("thing", "ab1", r"[a-z]+[0-9]", "letters, then a digit") == "ab1"
    assert check_identifier("thing", "ab1", re.compile(r"[a-z]+[0-9]"), "…") == "ab1"
    for bad in ("ab1\n", "ab12", " ab1", "xab1 ", "", None, 5, b"ab1"):
        with pytest.raises(ParameterError) as err:
            check_identifier("thing", bad, r"[a-z]+[0-9]", "letters, then a digit")
        assert str(err.value) == f"thing {bad!r} is not allowed: letters, then a digit"
    # the bug this module exists for: re.match with "$" accepts a trailing newline
    assert re.match(r"^[a-z]+[0-9]$", "ab1\n")


@pytest.mark.parametrize("value", ["P03\n", "P03\r\n", "\nP03", "P03\x00"])
def test_a_participant_id_with_a_newline_is_refused(value):
    with pytest.raises(ParameterError, match=re.escape(f"participant id {value!r} is not "
                                                       "allowed: use 1-32 letters or digits")):
        check_participant_id(value)
    assert check_participant_id("P03") == "P03"


@pytest.mark.parametrize("value", ["abc\n", "abc\r\n", "run.1\n"])
def test_a_run_name_with_a_newline_is_refused(value):
    message = (f"run name {value!r} is not allowed: use 1-64 letters, digits, '.', '_' or '-', "
               "starting with a letter or digit")
    with pytest.raises(ParameterError) as err:
        check_run_name(value)
    assert str(err.value) == message  # the message of talkingface.paths, unchanged
    with pytest.raises(ParameterError, match="run name"):
        RunPaths.create(value)


@pytest.mark.parametrize("name, ok", [("abc", True), ("a.b_c-1", True), ("x" * 64, True),
                                      ("x" * 65, False), ("a..b", False), ("..", False),
                                      (".a", False), ("-a", False), ("a/b", False),
                                      ("a b", False), ("", False)])
def test_run_names_as_before(name, ok):
    if ok:
        assert check_run_name(name) == name
    else:
        with pytest.raises(ParameterError, match="is not allowed"):
            check_run_name(name)


def test_stimulus_ids():
    for sid in ("synthetic-smile-good", "real-neutral-normal", "audio-bad"):
        assert check_stimulus_id(sid) == sid
    for sid in ("synthetic-smile-good\n", "audio-bad\n", "audio", "Audio-bad", "a-b-c-d",
                "audio-bad/../x", ""):
        with pytest.raises(ParameterError, match=re.escape(f"stimulus id {sid!r} is not "
                                                           "allowed: two or three lowercase")):
            check_stimulus_id(sid)


def test_the_command_line_refuses_a_report_name_with_a_newline(tmp_path, monkeypatch, capsys):
    from talkingface.cli.main import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "study").mkdir()
    assert main(["report", "--study-data", "study", "--name", "abc\n"]) == 2
    assert "error: run name 'abc\\n' is not allowed" in capsys.readouterr().err
    assert not (tmp_path / "reports").exists()
