"""Outputs: which paths a command may write (checked before any work), and writing them so that
nothing is half-written.

The rule, for every command and every output option (``-o``, ``--report``), in one place
(``check_outputs``): the parent directory exists and is writable; the name fits the kind of
output (an ``OutputKind``: a model ``.npz``, a physics CONFIG ``.json``, a recording as a bag
directory or a ``.mcap`` file, a report directory; a file format's kind is defined with its
reader, ``model.MODEL`` and ``physics.config.CONFIG``); it is not one of the command's inputs
(nor inside one, nor holding one); and an existing path is replaced only with ``--force`` and only when it is
the same kind of output written by this tool (a recording carrying this tool's mark in its
rosbag2 metadata by a recording, a model by a model, a report folder this tool made by a report;
an empty directory takes a report, with or without --force, as there is nothing in it to lose).
Anything else the user owns (a bench log ``ros2 bag record`` wrote, say) is refused, never deleted.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import struct
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from . import quiet_start
from .errors import BadInputError, OutputExistsError
from .specs import spec_path

#: File in every report directory the tool writes: only such a directory is replaced by a report.
REPORT_MARKER = ".bldc-propulsion-report"
#: Entry of rosbag2's own ``custom_data`` (metadata.yaml, and the MCAP file's ``rosbag2`` metadata
#: record) in every recording the tool writes: only such a recording is replaced by --force, so a
#: typo cannot wipe a bench log. ``ros2 bag info/play`` read custom_data as free key-value pairs.
RECORDING_MARK = ("written_by", "bldc-propulsion")
#: Name endings that say "a file of another kind": refused as a recording or report directory.
_FILE_SUFFIXES = (".npz", ".json", ".csv", ".db3", ".yaml", ".yml", ".txt", ".html", ".png",
                  ".py", ".npy", ".zip")


def describe_path(path: str | os.PathLike[str]) -> str:
    """What a path holds, for messages ("a JSON file", "a directory with 3 entries"): so that a
    refusal or a wrong --model says what the file *is*, not what failed inside a parser."""
    p = Path(path)
    if p.is_dir():
        if (p / "metadata.yaml").is_file():
            return "a rosbag2 recording (directory)"
        if (p / REPORT_MARKER).is_file():
            return "a report directory"
        n = sum(1 for _ in p.iterdir())
        return f"a directory with {n} entr{'y' if n == 1 else 'ies'}" if n else "an empty directory"
    if not p.exists():
        return "nothing (no such file)"
    try:
        with open(p, "rb") as fh:
            head = fh.read(512)
    except OSError as exc:
        return f"an unreadable file ({exc.strerror or exc})"
    if not head:
        return "an empty file"
    for magic, what in ((b"PK\x03\x04", "a zip archive (.npz)"), (b"\x89MCAP", "an MCAP recording"),
                        (b"SQLite format 3", "an SQLite database"), (b"\x93NUMPY", "a single NumPy array (.npy)"),
                        (b"\x89PNG", "a PNG image"), (b"\x80", "a Python pickle")):
        if head.startswith(magic):
            return what
    text = head.lstrip()
    if text[:1] in (b"{", b"["):
        return "a JSON file"
    if text[:5].lower() in (b"<!doc", b"<html"):
        return "an HTML file"
    try:
        head.decode("utf-8")
    except UnicodeDecodeError:
        return "a binary file"
    return "a text file"


@dataclass(frozen=True)
class OutputKind:
    """One kind of output: how its name must end and how to recognise an existing one."""

    name: str  #: "recording", "model", ...
    what: str  #: what the user must give, for messages
    suffixes: tuple[str, ...]  #: allowed endings; () = a directory (no file ending)
    holds: Callable[[Path], bool]  #: an existing path is this kind of output (may be replaced)

    def name_fits(self, path: Path) -> bool:
        if self.suffixes:
            return path.suffix.lower() in self.suffixes
        return path.suffix.lower() not in _FILE_SUFFIXES


def _is_recording(p: Path) -> bool:
    if p.is_dir():
        return (p / "metadata.yaml").is_file()
    if p.is_file() and p.suffix == ".mcap":
        with open(p, "rb") as fh:
            return fh.read(5) == b"\x89MCAP"
    return False


def _custom_data(yaml_text: str) -> dict[str, object]:
    """``custom_data`` of rosbag2 metadata (the whole metadata.yaml, or the bare mapping an MCAP
    file stores); {} when absent or unreadable."""
    from ruamel.yaml import YAML  # late: only when a recording is to be replaced (rosbags' own YAML)
    from ruamel.yaml.error import YAMLError

    try:
        meta = YAML(typ="safe", pure=True).load(yaml_text)
    except YAMLError:
        return {}
    if isinstance(meta, dict) and isinstance(meta.get("rosbag2_bagfile_information"), dict):
        meta = meta["rosbag2_bagfile_information"]
    data = meta.get("custom_data") if isinstance(meta, dict) else None
    return data if isinstance(data, dict) else {}


_U32, _U64 = struct.Struct("<I"), struct.Struct("<Q")


def _mcap_rosbag2_metadata(p: Path) -> str | None:
    """The ``serialized_metadata`` of the ``rosbag2`` metadata record of an MCAP file (where
    rosbag2 keeps metadata.yaml's content in a single-file recording), found through the
    summary's metadata index; None when the file has none or is not well formed."""
    def string(buf: bytes, at: int) -> tuple[str, int]:
        (n,) = _U32.unpack_from(buf, at)
        return buf[at + 4:at + 4 + n].decode("utf-8"), at + 4 + n

    try:
        with open(p, "rb") as fh:
            size = fh.seek(0, os.SEEK_END)
            fh.seek(size - 37)  # footer record (opcode, length, 20 bytes) + closing magic
            tail = fh.read(37)
            if tail[0] != 0x02 or tail[29:] != b"\x89MCAP0\r\n":
                return None
            (summary_start,) = _U64.unpack_from(tail, 9)
            if not 0 < summary_start < size - 37:
                return None
            fh.seek(summary_start)
            summary = fh.read(size - 37 - summary_start)
            at = 0
            while at + 9 <= len(summary):  # every summary record: the metadata index among them
                op, (n,) = summary[at], _U64.unpack_from(summary, at + 1)
                body = summary[at + 9:at + 9 + n]
                at += 9 + n
                if op != 0x0D or string(body, 16)[0] != "rosbag2":
                    continue
                fh.seek(_U64.unpack_from(body, 0)[0])
                record = fh.read(_U64.unpack_from(body, 8)[0])
                if record[0] != 0x0C:
                    return None
                _, i = string(record, 9)
                (end,) = _U32.unpack_from(record, i)
                i, end = i + 4, i + 4 + end
                while i < end:
                    key, i = string(record, i)
                    value, i = string(record, i)
                    if key == "serialized_metadata":
                        return value
    except (OSError, IndexError, ValueError, struct.error):
        return None
    return None


def recording_custom_data(p: Path) -> dict[str, object]:
    """The rosbag2 ``custom_data`` of the recording at ``p`` (a bag directory's metadata.yaml, or
    a single MCAP file's rosbag2 metadata record); {} when it has none or cannot be read."""
    if p.is_dir():
        try:
            text: str | None = (p / "metadata.yaml").read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError):
            return {}
    else:
        text = _mcap_rosbag2_metadata(p)
    return {} if text is None else _custom_data(text)


def recording_marked(p: Path) -> bool:
    """The recording at ``p`` carries RECORDING_MARK in its rosbag2 metadata: this tool wrote it."""
    key, value = RECORDING_MARK
    return recording_custom_data(p).get(key) == value


def recognised_by(load: Callable[[Path], object]) -> Callable[[Path], bool]:
    """``OutputKind.holds`` of a file format: a file that ``load`` reads without a BadInputError.
    The module that owns a format defines its kind with its own reader (``model.MODEL``,
    ``physics.config.CONFIG``), so that this module needs none of them."""
    def holds(p: Path) -> bool:
        if not p.is_file():
            return False
        try:
            load(p)
        except BadInputError:
            return False
        return True
    return holds


RECORDING = OutputKind("recording", "a recording (a bag directory or a .mcap file)", (),
                       lambda p: _is_recording(p) and recording_marked(p))
#: A recording may also be a single .mcap file: ``name_fits`` is special-cased for it.


def _empty_dir(p: Path) -> bool:
    """An empty real directory (not a link to one): nothing in it to lose."""
    return p.is_dir() and not p.is_symlink() and not any(p.iterdir())


#: A report replaces a report this tool made, or an empty directory (a user who made the folder
#: first: nothing is lost, so it needs no --force either).
REPORT = OutputKind("report", "a report directory", (),
                    lambda p: p.is_dir() and ((p / REPORT_MARKER).is_file() or _empty_dir(p)))


def _free(final: Path, kind: OutputKind | None) -> bool:
    """Nothing is there that --force would have to allow replacing: no such path, or an empty
    directory where a report goes."""
    if not (final.exists() or final.is_symlink()):
        return True
    return kind is REPORT and _empty_dir(final)


def _name_fits(kind: OutputKind, path: Path) -> bool:
    if kind is RECORDING and path.suffix.lower() == ".mcap":
        return True
    return kind.name_fits(path)


def _inside(inner: Path, outer: Path) -> bool:
    return inner == outer or outer in inner.parents


def _same(a: Path, b: Path) -> bool:
    """Same file or directory: resolved paths, and the same inode (hard links, bind mounts)."""
    if a.resolve() == b.resolve():
        return True
    with contextlib.suppress(OSError):
        return a.exists() and b.exists() and os.path.samefile(a, b)
    return False


def check_output(path: str | os.PathLike[str], kind: OutputKind, *, force: bool = False,
                 inputs: Iterable[str | os.PathLike[str] | None] = (), option: str = "-o") -> Path:
    """Refuse (BadInputError, one line naming ``option`` and the path) an output that breaks the
    rule of this module; returns the path. Call it before any work, so that a wrong path costs
    nothing; ``atomic_output`` applies the same-kind rule again when it replaces."""
    final = Path(path)
    where = f"{option} {final}"
    if not str(path):
        raise BadInputError(f"{option}: an output path is required")
    if not _name_fits(kind, final):
        if kind.suffixes:
            raise BadInputError(f"{where}: must be {kind.what}: the name must end in {' or '.join(kind.suffixes)}")
        raise BadInputError(f"{where}: must be {kind.what}, but '{final.suffix}' names another kind of file")
    parent = final.parent
    if not parent.is_dir():
        raise BadInputError(f"{where}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise BadInputError(f"{where}: directory {parent} is not writable")
    resolved = final.resolve()
    for src in inputs:
        if src is None or not str(src):
            continue
        s = Path(spec_path(src))  # a recording named PATH@NS is the file PATH
        if _same(final, s) or _inside(resolved, s.resolve()) or _inside(s.resolve(), resolved):
            raise BadInputError(f"{where}: is (or holds, or lies inside) the input {s} of this command; "
                                "an output never replaces an input")
    if not _free(final, kind):
        if not force:
            raise OutputExistsError(f"{final}: already exists (use --force to replace it)")
        _check_replaceable(final, kind, where)
    return final


def _check_replaceable(final: Path, kind: OutputKind, where: str) -> None:
    if final.is_symlink() or not kind.holds(final):
        if kind is RECORDING and not final.is_symlink() and _is_recording(final):
            where_mark = "its metadata.yaml" if final.is_dir() else "its rosbag2 metadata record"
            raise BadInputError(f"{where}: exists and is a recording that was not written by bldc-propulsion "
                                f"(no mark in {where_mark}); remove it yourself if you mean it")
        found = "a symbolic link" if final.is_symlink() else describe_path(final)
        raise BadInputError(f"{where}: exists and is {found}, not {kind.what} this tool wrote; "
                            "--force only replaces the same kind of output, so it is left as it is")


def check_outputs(outputs: Sequence[tuple[str | os.PathLike[str] | None, OutputKind, str]], *,
                  force: bool, inputs: Iterable[str | os.PathLike[str] | None] = ()) -> None:
    """``check_output`` for each (path, kind, option) given (None = option not used), and no
    two outputs of one command on the same path (or one inside the other)."""
    given = [(Path(p), k, o) for p, k, o in outputs if p is not None]
    ins = list(inputs)
    for path, kind, option in given:
        check_output(path, kind, force=force, inputs=ins, option=option)
    for i, (a, _, oa) in enumerate(given):
        for b, _, ob in given[i + 1:]:
            if _inside(a.resolve(), b.resolve()) or _inside(b.resolve(), a.resolve()):
                raise BadInputError(f"{oa} {a} and {ob} {b}: two outputs of one command on the same path")


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike[str], force: bool = False,
                  kind: OutputKind | None = None) -> Iterator[Path]:
    """Yield a staging path with the final name; move it to ``path`` when the block succeeds.

    The staging path lives in a hidden directory beside ``path`` and has the same base name,
    so writers that derive inner file names from it (a rosbag2 directory names its .mcap
    after itself) produce the same files as a direct write. On any exception
    (KeyboardInterrupt included) the staging directory is removed and an existing ``path``
    stays untouched; so it is after a Ctrl-C whose KeyboardInterrupt never reached the block
    (``quiet_start.interrupted``). An existing ``path`` is refused unless ``force``, and with ``kind`` also
    unless it is that kind of output (checked again at the rename: what the user owns is
    never replaced, even if it appeared during the work).
    """
    final = Path(path)
    if not force and not _free(final, kind):
        raise OutputExistsError(f"{final}: already exists (use --force to replace it)")
    parent = final.parent
    if not parent.is_dir():
        raise BadInputError(f"{final}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise BadInputError(f"{final}: directory {parent} is not writable")
    if kind is not None and (final.exists() or final.is_symlink()):
        _check_replaceable(final, kind, str(final))
    stage = parent / f".{final.name}.partial-{os.getpid()}"
    _remove(stage)
    try:  # mkdir inside: a Ctrl-C right after it must still remove the staging directory
        stage.mkdir()
        tmp = stage / final.name
        yield tmp
        if quiet_start.interrupted():  # a Ctrl-C whose KeyboardInterrupt was swallowed on the way
            raise KeyboardInterrupt
        if not tmp.exists():
            raise RuntimeError(f"{final}: nothing was written")
        backup = stage / f"{final.name}.old"
        if final.exists() or final.is_symlink():
            if kind is not None:
                _check_replaceable(final, kind, str(final))
            os.replace(final, backup)
        try:
            os.replace(tmp, final)
        except BaseException:
            if backup.exists():
                os.replace(backup, final)
            raise
    finally:
        _remove(stage)


@contextlib.contextmanager
def report_output(path: str | os.PathLike[str], force: bool = False) -> Iterator[Path]:
    """A report directory written whole: yields an empty staging directory (with the marker
    that makes it replaceable by the next report) that replaces ``path`` when the block
    succeeds, so no file of an earlier report (a stale PNG) survives and a failure keeps it."""
    with atomic_output(path, force=force, kind=REPORT) as tmp:
        tmp.mkdir()
        (tmp / REPORT_MARKER).write_text("written by bldc-propulsion; --force replaces this directory whole\n",
                                         encoding="utf-8")
        yield tmp
