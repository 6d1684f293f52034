"""The project's exception hierarchy.

Every package raises these, so a caller can catch ``TalkingFaceError`` for anything the project
itself refuses. Messages name the parameter or file, the value received, and what is allowed.
"""


class TalkingFaceError(Exception):
    """Root of all errors raised deliberately by talkingface."""


class ParameterError(TalkingFaceError, ValueError):
    """A parameter, configuration value or input array is not acceptable."""


class CorpusError(TalkingFaceError):
    """A corpus folder or one of its files is missing, malformed or inconsistent."""


class NotFittedError(TalkingFaceError, AttributeError):
    """An estimator was used before ``fit`` was called."""
