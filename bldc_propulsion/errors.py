"""Error types the command line turns into one-line messages (exit 2) or faults (exit 1)."""

from __future__ import annotations


class BldcError(Exception):
    """Base of every error this package raises on purpose."""


def one_line(exc: BaseException, limit: int = 200) -> str:
    """An exception's text on one line, cut to ``limit`` characters: for one-line errors."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) < limit else text[: limit - 3] + "..."


class BadInputError(BldcError):
    """The user's input is wrong (file, topic, parameter): exit status 2, one line on stderr."""


class BagError(BadInputError):
    """A recording cannot be read or written as needed."""


class ModelError(BadInputError):
    """A model file is missing, corrupt or does not fit what is asked of it."""


class OutputExistsError(BadInputError):
    """An output already exists and --force was not given."""
