"""The command line: ``talkingface <command>`` (:mod:`~talkingface.cli.main`), its shared
arguments (:mod:`~talkingface.cli.args`), the run-level commands that run stages and log them
(:mod:`~talkingface.cli.runs`), the ``study``, ``cache`` and ``server`` commands, and the
``animate`` / ``stream`` commands with live audio (:mod:`~talkingface.cli.animate`,
:mod:`~talkingface.live`)."""
