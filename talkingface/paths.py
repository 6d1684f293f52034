"""Every path the pipeline reads or writes, in one place.

::

    runs/<name>/
      config.yaml    the resolved config of the last invocation
      corpus/        data_synth output, or a given corpus linked in (the corpus contract)
      units/         motion_units.npz, variance.csv
      keyframes/     keyframes.npz, roundtrip.csv, keyframes.png
      tracking/      the MU-constrained tracker on rendered video: error_curve.csv/.png
      tracked/       the corpus as the tracker sees it (mapping.visual_source tracked)
      mapping/       trained mappings, Tables I-II (CSV), ranking, gate accuracy, plots
      speech_eval/   the mappings scored on real speech (analysis/real_speech/), the recogniser bar
      render/        Fig. 6 / Fig. 7-style pictures and keyframe tracks of a held-out sentence
      stimuli/       the perception study's stimuli and manifest
      study_data/    the simulated participants (psych-DS)
      analysis/      Tables III-VII, statistics and model fits of study_data
      ablations/     one folder per ablation setting and results.csv
      report/        figures and the summary the PDF is built from
    reports/<name>.pdf
    cache/           what tasks, stages and runs share, by content (`talkingface cache clean`);
                     $TALKINGFACE_CACHE names another folder for every run (e.g. one cache for
                     several working folders: the test suite shares one across its runs)

Every stage folder holds the ``config.yaml`` it ran under and a ``done.json`` written last (see
:mod:`talkingface.stages.base`).
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

from groundwork.errors import ParameterError
from groundwork.identifiers import check_identifier

# 1-64 letters, digits, ._- starting with a letter or digit, and no ".." anywhere
_NAME = re.compile(r"(?!.*\.\.)[A-Za-z0-9][A-Za-z0-9._-]{0,63}")

# the environment variable that names the cache folder of every run (default: cache/ beside runs/)
CACHE_ENV = "TALKINGFACE_CACHE"

STAGE_FOLDERS = ("corpus", "units", "keyframes", "tracking", "tracked", "mapping", "front_end",
                 "voices", "speech_eval", "render", "stimuli", "study_data", "analysis", "ablations",
                 "ceiling", "articulation", "real_speaker", "real_faces", "real_steps",
                 "report")


def check_run_name(name: str) -> str:
    """A run name is 1–64 letters, digits, ``._-``, starting with a letter or digit."""
    return check_identifier("run name", name, _NAME, "use 1-64 letters, digits, '.', '_' or "
                            "'-', starting with a letter or digit")


@dataclass(frozen=True)
class RunPaths:
    """The folders of one run (see the module docstring).

    ``RunPaths.create(name)``: ``runs/<name>`` of the command line. ``RunPaths.at(folder)``: a
    run in any folder, e.g. a run nested in a stage of another run (``run(["units",
    "mapping"], RunPaths.at(folder, cache_dir=outer.cache), cfg)``).
    """

    name: str
    root: Path  # runs/<name>
    reports_dir: Path
    building: tuple = ()  # (stage, folder): a stage being built in a temporary folder
    cache_dir: Path | None = None  # None: cache/ beside runs/ (see :attr:`cache`)

    def building_in(self, name: str, folder: Path) -> "RunPaths":
        """These paths with stage ``name`` written to ``folder`` (a stage is built beside its
        final folder and renamed into place only when it completed)."""
        return RunPaths(self.name, self.root, self.reports_dir, (name, Path(folder)),
                        self.cache_dir)

    @classmethod
    def create(cls, name: str, *, runs_dir="runs", reports_dir="reports") -> "RunPaths":
        check_run_name(name)
        return cls(name, Path(runs_dir) / name, Path(reports_dir))

    @classmethod
    def at(cls, folder, *, reports_dir=None, cache_dir=None) -> "RunPaths":
        """The run in ``folder`` (any folder, named after it; no name rules).

        Parameters
        ----------
        folder : path-like
            The run's folder: its stages' folders are made in it.
        reports_dir : path-like, optional
            Where its report's PDF goes (default: ``folder`` itself).
        cache_dir : path-like, optional
            The content-keyed cache to share (default: ``cache/`` two levels above ``folder``,
            as for ``runs/<name>``); a run nested in another run's stage passes the outer
            run's :attr:`cache`.
        """
        folder = Path(folder)
        return cls(folder.name, folder, Path(reports_dir) if reports_dir else folder,
                   cache_dir=Path(cache_dir) if cache_dir else None)

    def stage(self, name: str) -> Path:
        """The folder of stage ``name`` (one of :data:`STAGE_FOLDERS`)."""
        if name not in STAGE_FOLDERS:
            raise ParameterError(f"unknown stage {name!r}; allowed: {', '.join(STAGE_FOLDERS)}")
        if self.building and self.building[0] == name:
            return self.building[1]
        return self.root / name

    @property
    def cache(self) -> Path:
        """The content-keyed cache beside ``runs/`` (:mod:`groundwork.cache`): what tasks,
        stages and runs share (a corpus's features, its recognised phones); ``cache_dir`` when
        set, else the folder ``$TALKINGFACE_CACHE`` names (:data:`CACHE_ENV`) when set. An
        entry's key is its content, so sharing one folder between runs changes no result."""
        if self.cache_dir is not None:
            return self.cache_dir
        given = os.environ.get(CACHE_ENV, "").strip()
        return Path(given) if given else self.root.parent.parent / "cache"

    @property
    def config(self) -> Path:
        return self.root / "config.yaml"

    @property
    def corpus(self) -> Path:
        return self.stage("corpus")

    @property
    def units(self) -> Path:
        return self.stage("units")

    @property
    def units_model(self) -> Path:
        return self.units / "motion_units.npz"

    @property
    def keyframes(self) -> Path:
        return self.stage("keyframes")

    @property
    def keyframes_model(self) -> Path:
        return self.keyframes / "keyframes.npz"

    @property
    def tracking(self) -> Path:
        return self.stage("tracking")

    @property
    def tracked(self) -> Path:
        return self.stage("tracked")

    @property
    def mapping(self) -> Path:
        return self.stage("mapping")

    @property
    def speech_eval(self) -> Path:
        return self.stage("speech_eval")

    @property
    def render(self) -> Path:
        return self.stage("render")

    @property
    def stimuli(self) -> Path:
        return self.stage("stimuli")

    @property
    def study_data(self) -> Path:
        return self.stage("study_data")

    @property
    def analysis(self) -> Path:
        return self.stage("analysis")

    @property
    def ablations(self) -> Path:
        return self.stage("ablations")

    @property
    def report_dir(self) -> Path:
        return self.stage("report")

    @property
    def pdf(self) -> Path:
        return self.reports_dir / f"{self.name}.pdf"
