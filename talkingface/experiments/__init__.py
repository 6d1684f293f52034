"""MLflow: what the runs log (:mod:`~talkingface.experiments.log`), the logged mapping model
(:mod:`~talkingface.experiments.pyfunc`), the UI that opens on the runs
(:mod:`~talkingface.experiments.mlflow_app`) and the lab's tracking server
(:mod:`~talkingface.experiments.server`). The stages never import it; the command line does."""
