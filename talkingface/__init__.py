"""talkingface: the pipeline's top floor.

Sub-packages, each importing only those after it: :mod:`talkingface.cli` (the command line)
→ :mod:`talkingface.experiments` (MLflow logging, the UI and the lab's server) →
:mod:`talkingface.stages` (every stage, ``(paths, cfg) -> results``) → the modules every one of
them reads: :mod:`~talkingface.config`, :mod:`~talkingface.paths`,
:mod:`~talkingface.executor` (where tasks run) and :mod:`~talkingface.provenance`.
"""
__version__ = "0.1.0"
