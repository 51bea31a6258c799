"""A recording as a command names it: ``PATH`` or ``PATH@NAMESPACE``.

A vehicle's recording holds every motor under its own namespace (interfaces.md, "A
quadrotor"); ``--namespace`` picks one motor for every recording of a command, so training on
motor0 and validating on motor1 of the same flight needs a namespace per recording:
``flight@motor0``. A leaf module (imports nothing of the package) so that bagio, atomic and
the commands share one reading of the suffix.
"""

from __future__ import annotations

import os

#: Separates a recording's path from the motor's namespace: ``flight.mcap@motor1``.
SEPARATOR = "@"


def split_spec(spec: str | os.PathLike[str], namespace: str | None = None) -> tuple[str, str | None]:
    """(path, namespace) of ``spec``: a path that exists is taken as written (a file or folder
    may contain '@'); else ``PATH@NS`` whose PATH exists gives NS, which wins over the command's
    ``namespace``; anything else is returned unchanged (the caller's open fails with its own
    'no such recording')."""
    text = os.fspath(spec)
    if SEPARATOR not in text or os.path.exists(text):
        return text, namespace
    path, _, ns = text.rpartition(SEPARATOR)
    if path and os.path.exists(path):
        return path, ns
    return text, namespace


def spec_path(spec: str | os.PathLike[str]) -> str:
    """The recording's path of ``spec`` (the namespace suffix dropped)."""
    return split_spec(spec)[0]
