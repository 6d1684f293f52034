"""Fixtures shared by the command-line tests."""
import pytest


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    """A temporary working directory with its own MLflow store."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    return tmp_path
