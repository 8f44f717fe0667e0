"""Files a command writes where the user told it to: never over an existing file unless asked, never
over or inside one of its own inputs, and never half-written.

`check_output` refuses, before any work is done, an output that exists (unless `--overwrite`), that
is a folder, or that is one of the command's inputs or lies inside an input folder (even with
`--overwrite`: that would destroy the data the output is computed from, or put a stray file among
them that the next reading of the folder takes for data).  `check_output_folder` applies the same rule to a
folder of outputs.  `atomic_output` gives a temporary path beside the output,
with the same suffix (writers such as `np.savez` and matplotlib choose the format by it), and
renames it into place only when the writer finished: an interrupted or failed write leaves the
previous file, if any, as it was.  `check_report` and `write_report` do both for the report.md / report.json
pair of the commands and studies that write one.  `exclusive_folder` holds a folder of outputs for one
process: two commands writing one folder at once would each write a report of its own files, the last
one replacing the other's.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
import sys
import time
from collections.abc import Iterable, Iterator
from pathlib import Path

OVERWRITE_FLAG = "--overwrite"


class OutputError(ValueError):
    """An output path that would destroy something or cannot be written; the message names it."""


def check_output(path: str | Path, overwrite: bool, inputs: Iterable[str | Path] = (), flag: str = "--output") -> Path:
    """`path` as a Path once it is safe to write there later; else an `OutputError` naming it and `flag`."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{flag} {path}: is a folder; give a file name (e.g. {path / 'poses'}{path.suffix or '.json'})")
    _refuse_inside_inputs(path, inputs, flag)
    if path.exists() and not overwrite:
        raise OutputError(f"{flag} {path}: exists; pass {OVERWRITE_FLAG} to replace it")
    if not path.parent.exists():
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as error:  # a read-only file system, no permission
            raise OutputError(f"{flag} {path}: its folder {path.parent} cannot be made ({error.strerror})") from None
    if not os.access(path.parent, os.W_OK):
        raise OutputError(f"{flag} {path}: its folder {path.parent} cannot be written")
    return path


def check_output_folder(folder: str | Path, inputs: Iterable[str | Path] = (), flag: str = "--output") -> Path:
    """`folder` as a Path once it is safe to write outputs into it: not a file, not an input, not inside
    an input folder.  The files written into it are each checked with `check_output`."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{flag} {folder}: is a file; give a folder")
    _refuse_inside_inputs(folder, inputs, flag)
    return folder


def _refuse_inside_inputs(path: Path, inputs: Iterable[str | Path], flag: str) -> None:
    target = path.resolve()
    for given in inputs:
        source = Path(given).resolve()
        if target == source:
            raise OutputError(f"{flag} {path}: is this command's input {given}; writing there would destroy it, choose another path")
        if source.is_dir() and target.is_relative_to(source):
            raise OutputError(
                f"{flag} {path}: is inside this command's input folder {given}; outputs never go among the inputs, choose a path outside it"
            )


@contextlib.contextmanager
def atomic_output(path: str | Path) -> Iterator[Path]:
    """A temporary path to write `path`'s content to; renamed onto `path` when the block ends normally."""
    path = Path(path)
    temporary = path.with_name(f".{path.stem}.{os.getpid()}.partial{path.suffix}")
    try:
        yield temporary
        os.replace(temporary, path)
    except OSError as error:  # a full disk, a file system gone read-only: the earlier file, if any, is kept
        kept = "the earlier file is kept as it was" if path.exists() else "nothing was written there"
        raise OutputError(f"{path}: could not be written ({error.strerror or error}); {kept}") from None
    finally:
        temporary.unlink(missing_ok=True)


REPORT_FILES = ("report.md", "report.json")


def check_report(folder: Path, overwrite: bool, flag: str = "--output") -> None:
    """`check_output` of the report pair in `folder`, before any work."""
    for name in REPORT_FILES:
        check_output(folder / name, overwrite, flag=flag)


def write_report(folder: Path, report: dict, markdown: str, echo: bool = True) -> None:
    """report.json and report.md in `folder` (made if absent), each written atomically; with `echo` the
    markdown also to stderr, where the command's log goes."""
    folder.mkdir(parents=True, exist_ok=True)
    with atomic_output(folder / "report.json") as temporary:
        temporary.write_text(json.dumps(report, indent=2, default=float))
    with atomic_output(folder / "report.md") as temporary:
        temporary.write_text(markdown)
    if echo:
        print(markdown, file=sys.stderr)


@contextlib.contextmanager
def exclusive_folder(folder: Path, lock_file: str, flag: str, holder: str) -> Iterator[None]:
    """Hold `folder` for this process: a second one to ask for it stops at once, in one line naming the
    first (`holder` says what holds such a folder: "run", "jaxpose.reconstruct").

    The lock is an OS lock on `folder/lock_file` (released by the kernel if the process dies, so a killed
    process never leaves the folder locked); the file names the holder for the message and is removed at the
    end.  A folder (and parents) made only to hold the lock is removed again if nothing else was written.
    """
    made = [entry for entry in (folder, *folder.parents) if not entry.exists()]  # deepest first
    path = folder / lock_file
    try:
        folder.mkdir(parents=True, exist_ok=True)
        descriptor = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as error:
        raise SystemExit(f"{flag} {folder}: cannot be written ({error.strerror})") from None
    try:
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
            if os.fstat(descriptor).st_ino != os.stat(path).st_ino:  # the holder removed it as we opened it
                raise BlockingIOError
        except (BlockingIOError, FileNotFoundError):
            named = os.pread(descriptor, 512, 0).decode(errors="replace").strip() or "another process"
            raise SystemExit(
                f"{flag} {folder} is in use by another {holder} ({named}); wait for it to end, or choose another {flag}"
            ) from None
        os.ftruncate(descriptor, 0)
        os.pwrite(descriptor, f"process {os.getpid()} on {socket.gethostname()}, started {time.strftime('%Y-%m-%d %H:%M:%S')}".encode(), 0)
        try:
            yield
        finally:
            os.unlink(path)
            for entry in made:
                if any(entry.iterdir()):
                    break
                entry.rmdir()
    finally:
        os.close(descriptor)
