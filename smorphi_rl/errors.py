"""Exceptions the library raises for bad input; the CLI turns them into one line on stderr."""

from __future__ import annotations


class SmorphiError(ValueError):
    """Any input the project cannot use: the message names the input and the problem."""


class MapError(SmorphiError):
    """A map file (YAML or image) that is missing, malformed or unusable."""


class MorphologyError(SmorphiError):
    """Hinge angles that are not numbers or lie outside [0, 180] degrees."""


class Interrupted(KeyboardInterrupt):
    """A stop request (Ctrl-C, SIGTERM) that ended a command with something to say: what it kept, and where."""
