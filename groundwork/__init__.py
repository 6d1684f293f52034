"""The ground floor: what every package of the project stands on, and nothing about faces.

The exception hierarchy (:mod:`~groundwork.errors`), checked settings fields
(:mod:`~groundwork.settings`), files written atomically (:mod:`~groundwork.atomic`), one owner of
a folder at a time (:mod:`~groundwork.owner`), identifiers that become file names
(:mod:`~groundwork.identifiers`), WAV and MP4 I/O (:mod:`~groundwork.audio`,
:mod:`~groundwork.movie`), the self-describing model file (:mod:`~groundwork.modelfile`), the
content-keyed array cache (:mod:`~groundwork.cache`), and per-process threads, memory and
reproducible linear algebra (:mod:`~groundwork.threads`, :mod:`~groundwork.memory`,
:mod:`~groundwork.numerics`).

It imports no other package of the project; every other package may import it.
"""
