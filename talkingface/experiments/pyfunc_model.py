"""The file MLflow runs to build the logged mapping model ("models from code").

Logging the model this way stores this source file, not a pickled Python object: loading a
logged model runs the project's own code and reads the ``.tfmap`` artifact as data
(:meth:`mapping.checkpoint.AudioMapping.load`), so nothing in the artifact store can execute.
"""
import mlflow.models

from talkingface.experiments.pyfunc import MappingModel

mlflow.models.set_model(MappingModel())
