"""Write outputs under a temporary name and rename when complete, so nothing is half-written."""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

from .errors import BadInputError, OutputExistsError


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike[str], force: bool = False) -> Iterator[Path]:
    """Yield a staging path with the final name; move it to ``path`` when the block succeeds.

    The staging path lives in a hidden directory beside ``path`` and has the same base name,
    so writers that derive inner file names from it (a rosbag2 directory names its .mcap
    after itself) produce the same files as a direct write. On any exception
    (KeyboardInterrupt included) the staging directory is removed and an existing ``path``
    stays untouched. An existing ``path`` is refused unless ``force``.
    """
    final = Path(path)
    if final.exists() and not force:
        raise OutputExistsError(f"{final}: already exists (use --force to replace it)")
    parent = final.parent
    if not parent.is_dir():
        raise BadInputError(f"{final}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise BadInputError(f"{final}: directory {parent} is not writable")
    stage = parent / f".{final.name}.partial-{os.getpid()}"
    _remove(stage)
    try:  # mkdir inside: a Ctrl-C right after it must still remove the staging directory
        stage.mkdir()
        tmp = stage / final.name
        yield tmp
        if not tmp.exists():
            raise RuntimeError(f"{final}: nothing was written")
        backup = stage / f"{final.name}.old"
        if final.exists():
            os.replace(final, backup)
        try:
            os.replace(tmp, final)
        except BaseException:
            if backup.exists():
                os.replace(backup, final)
            raise
    finally:
        _remove(stage)
