"""Every path the pipeline reads or writes, in one place.

::

    runs/<name>/
      config.yaml           the resolved config of the last invocation
      corpus/               data_synth output (the corpus contract)
      units/                motion_units.npz, variance.csv, summary.json, config.yaml
      tracked/              the corpus as the MU-constrained tracker sees it (visual_source
                            tracked): the corpus contract plus tracking.csv
      mapping/              trained mappings, Tables I-II (CSV), ranking, gate accuracy, plots
      ablations/            one folder per ablation setting and results.csv
      report/               figures and the summary the PDF is built from
    reports/<name>.pdf
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from face_model.errors import ParameterError

_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")


def check_run_name(name: str) -> str:
    """A run name is 1–64 letters, digits, ``._-``, starting with a letter or digit."""
    if not isinstance(name, str) or not _NAME.match(name) or ".." in name:
        raise ParameterError(f"run name {name!r} is not allowed: use 1-64 letters, digits, '.', "
                             "'_' or '-', starting with a letter or digit")
    return name


@dataclass(frozen=True)
class RunPaths:
    name: str
    root: Path  # runs/<name>
    reports_dir: Path

    @classmethod
    def create(cls, name: str, *, runs_dir="runs", reports_dir="reports") -> "RunPaths":
        check_run_name(name)
        return cls(name, Path(runs_dir) / name, Path(reports_dir))

    @property
    def config(self) -> Path:
        return self.root / "config.yaml"

    @property
    def corpus(self) -> Path:
        return self.root / "corpus"

    @property
    def units(self) -> Path:
        return self.root / "units"

    @property
    def units_model(self) -> Path:
        return self.units / "motion_units.npz"

    @property
    def tracked(self) -> Path:
        return self.root / "tracked"

    @property
    def mapping(self) -> Path:
        return self.root / "mapping"

    @property
    def ablations(self) -> Path:
        return self.root / "ablations"

    @property
    def report_dir(self) -> Path:
        return self.root / "report"

    @property
    def pdf(self) -> Path:
        return self.reports_dir / f"{self.name}.pdf"
