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


def first_few(items, n: int = 3, sep: str = "; ") -> str:
    """The first ``n`` of ``items`` joined by ``sep``, and how many more there are, for a message
    of one line however many things it names (``"a; b; c; and 297 more"``)."""
    items = [str(i) for i in items]
    more = f"{sep}and {len(items) - n} more" if len(items) > n else ""
    return sep.join(items[:n]) + more
