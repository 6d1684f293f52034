"""talkingface: the command line, the stage pipeline, configuration and paths."""
__version__ = "0.1.0"
