"""A rig project prepared once: its training and validation arrays kept beside the recordings.

Loading a project (reading every detection, aligning the cameras, undistorting, choosing the person)
is done once; its result is written to ``PROJECT/.jaxpose_cache/prepared-<key>/``: one ``.npy`` per
array of each part (``train.keypoints2d.npy``, ...), written row block by row block as the recordings
are prepared (`Assembly`), and ``project.json`` with the rest (cameras, layout, the per-recording
summaries, the sessions of a project without calibration; ``recovered.json`` for the rigs recovered,
one per session).  The next run with the same inputs and options
memory-maps the arrays (`read`): it starts in seconds, and a project larger than memory trains with
only the rows of each batch read from disk.

The key (`key`) digests every option that changes the arrays, the code's `VERSION`, and each input
file's path, size, modification and status-change times (``st_ctime``) and inode: a file edited,
replaced, touched or renamed is a miss.  The status-change time is what makes this safe without
reading the files: no tool can set it (``cp -p``, ``rsync -t``, archive extraction and ``os.utime``
keep the modification time but not it), so a file edited in place to the same size with its time
kept is a miss too.  A copy of the project is a miss once (new inodes and times), never stale.

The folder appears whole or not at all: it is written under a temporary name and renamed.  Only the
`KEEP` most recently used prepared folders are kept.  A cache that cannot be written (a read-only
project) is a warning; the arrays then stay in memory.

Nothing here unpickles: a project folder may sit on a shared drive, and a crafted file in its cache
must not run code.  The arrays load with ``allow_pickle=False`` and the recovered rig is JSON.
"""

from __future__ import annotations

import dataclasses
import errno
import hashlib
import json
import logging
import os
import shutil
import struct
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.file_cache import CACHE_DIR
from jaxpose.rig.recordings import printable

log = logging.getLogger(__name__)

VERSION = 3  # bump when the prepared arrays change meaning (3: one recovered rig per session)
PREFIX = "prepared-"
KEEP = 2
RECOVERED_JSON = "recovered.json"
_HEADER_BYTES = 128  # a fixed-length .npy header: the row count is set at the end without moving the data


def key(options: Mapping[str, Any], files: Iterable[Path]) -> str:
    """The cache key of `options` (every option that changes the prepared arrays, by name) and the input `files`."""
    digest = hashlib.blake2b(digest_size=16)
    digest.update(json.dumps({"version": VERSION, **options}, sort_keys=True, default=str).encode())
    for path in sorted(set(files)):
        try:
            status = os.stat(path)  # follows links: the content's file
        except OSError as error:
            found = "a symbolic link that loops" if error.errno == errno.ELOOP else f"a file that cannot be read ({error.strerror})"
            raise DataFormatError(printable(path), "a readable input file", found) from None
        digest.update(os.fsencode(path) + b"\0")
        digest.update(struct.pack("<5q", status.st_size, status.st_mtime_ns, status.st_ctime_ns, status.st_ino, status.st_dev))
    return digest.hexdigest()


def folder(root: Path, cache_key: str) -> Path:
    return root / CACHE_DIR / f"{PREFIX}{cache_key}"


class _GrowingNpy:
    """An .npy file written block by block, its row count written into its header when it is closed."""

    def __init__(self, path: Path, first: np.ndarray):
        self.path, self.dtype, self.row_shape, self.rows = path, first.dtype, first.shape[1:], 0
        self.file = open(path, "wb")
        self.file.write(b"\0" * _HEADER_BYTES)

    def append(self, block: np.ndarray) -> None:
        if block.dtype != self.dtype or block.shape[1:] != self.row_shape:
            raise ValueError(f"{self.path.name}: rows {block.dtype} {block.shape[1:]} after {self.dtype} {self.row_shape}")
        self.file.write(np.ascontiguousarray(block).tobytes())
        self.rows += len(block)

    def close(self) -> None:
        header = {"descr": np.lib.format.dtype_to_descr(self.dtype), "fortran_order": False, "shape": (self.rows, *self.row_shape)}
        text = repr(header).encode("latin1")
        body = text.ljust(_HEADER_BYTES - 11) + b"\n"  # magic 6 + version 2 + length 2 + body = _HEADER_BYTES
        self.file.seek(0)
        self.file.write(b"\x93NUMPY\x01\x00" + struct.pack("<H", len(body)) + body)
        self.file.close()


class Assembly:
    """The prepared arrays of each part ("train", "validation"), appended recording by recording: into
    growing .npy files in `directory`, or in memory where `directory` is None.  An array that a later
    recording starts (a ground truth) is filled with NaN for the rows before it."""

    def __init__(self, directory: Path | None):
        self.directory = directory
        self.files: dict[tuple[str, str], _GrowingNpy | list[np.ndarray]] = {}
        self.rows: dict[str, int] = {}

    def add(self, part: str, arrays: Mapping[str, np.ndarray | None]) -> None:
        count = len(next(iter(arrays.values())))
        start = self.rows.get(part, 0)
        for name, array in arrays.items():
            if array is None:
                if (part, name) in self.files:
                    self._write(part, name, np.full((count, *self._row_shape(part, name)), np.nan, np.float32))
                continue
            if (part, name) not in self.files and start:
                self._write(part, name, np.full((start, *array.shape[1:]), np.nan, array.dtype))
            self._write(part, name, array)
        self.rows[part] = start + count

    def _row_shape(self, part: str, name: str) -> tuple[int, ...]:
        target = self.files[part, name]
        return target.row_shape if isinstance(target, _GrowingNpy) else target[0].shape[1:]

    def _write(self, part: str, name: str, array: np.ndarray) -> None:
        if (part, name) not in self.files:
            self.files[part, name] = [] if self.directory is None else _GrowingNpy(self.directory / f"{part}.{name}.npy", array)
        self.files[part, name].append(array)

    def close(self) -> dict[str, dict[str, np.ndarray]] | None:
        """The files closed (read them with `read_arrays`), or in memory {part: {name: array}}."""
        if self.directory is not None:
            for target in self.files.values():
                target.close()
            return None
        arrays: dict[str, dict[str, np.ndarray]] = {}
        for (part, name), pieces in self.files.items():
            arrays.setdefault(part, {})[name] = np.concatenate(pieces)
        return arrays


def read_arrays(directory: Path) -> dict[str, dict[str, np.ndarray]]:
    """{part: {name: memory-mapped array}} of a prepared folder."""
    arrays: dict[str, dict[str, np.ndarray]] = {}
    for path in sorted(directory.glob("*.npy")):
        part, name = path.stem.split(".", 1)
        arrays.setdefault(part, {})[name] = np.load(path, mmap_mode="r", allow_pickle=False)
    return arrays


def start(root: Path, cache_key: str) -> Path | None:
    """A fresh temporary folder to prepare into (None, with a warning, where the project cannot be written)."""
    cache = root / CACHE_DIR
    try:
        cache.mkdir(exist_ok=True)
        for stale in cache.glob(f"{PREFIX}*.tmp-*"):  # left by a run that was interrupted
            pid = int(stale.name.rsplit("-", 1)[1])
            if not _alive(pid):
                shutil.rmtree(stale, ignore_errors=True)
        temporary = cache / f"{PREFIX}{cache_key}.tmp-{os.getpid()}"
        shutil.rmtree(temporary, ignore_errors=True)
        temporary.mkdir()
        return temporary
    except (OSError, ValueError) as error:
        log.warning("the prepared project is not cached (%s cannot be written: %s); it stays in memory", cache, error)
        return None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    return True


def commit(temporary: Path, cache_key: str, meta: Mapping[str, Any], recovered: object | None) -> Path:
    """Write the metadata, then move the folder to its final name (another process's finished folder
    of the same key wins); older prepared folders beyond `KEEP` are removed."""
    (temporary / "project.json").write_text(json.dumps(meta, indent=1))
    if recovered is not None:
        (temporary / RECOVERED_JSON).write_text(json.dumps(_to_json(recovered)))
    final = temporary.parent / f"{PREFIX}{cache_key}"
    try:
        os.rename(temporary, final)
    except OSError:  # the same key finished meanwhile: keep that one
        shutil.rmtree(temporary, ignore_errors=True)
    _prune(final.parent)
    return final


def _prune(cache: Path) -> None:
    done = [path for path in cache.glob(f"{PREFIX}*") if ".tmp-" not in path.name]
    for old in sorted(done, key=lambda path: path.stat().st_mtime, reverse=True)[KEEP:]:
        log.info("removing the older prepared project %s", old)
        shutil.rmtree(old, ignore_errors=True)


def read_meta(directory: Path, recovered_type: Any = None) -> tuple[dict[str, Any], object | None]:
    """(project.json, the recovered calibrations as a `recovered_type` (session -> calibration) or None) of a prepared folder;
    marks it as just used.  A file that does not decode is a `DataFormatError` naming it."""
    meta = json.loads((directory / "project.json").read_text())
    recovered = None
    path = directory / RECOVERED_JSON
    if recovered_type is not None and path.exists():
        try:
            recovered = _from_json(recovered_type, json.loads(path.read_text()))
        except (ValueError, TypeError, KeyError) as error:
            raise DataFormatError(printable(path), f"a recovered rig written by jaxpose (delete the folder {directory} to prepare again)", str(error)) from None
    os.utime(directory)
    return meta, recovered


def _to_json(value: Any) -> Any:
    """A frozen dataclass of numpy arrays, numbers, strings, tuples and dicts (a recovered calibration) as JSON."""
    if dataclasses.is_dataclass(value):
        return {field.name: _to_json(getattr(value, field.name)) for field in dataclasses.fields(value)}
    if isinstance(value, np.ndarray) or hasattr(value, "__array__") and not isinstance(value, (int, float, bool)):
        array = np.asarray(value)
        return {"ndarray": array.tolist(), "dtype": array.dtype.str}
    if isinstance(value, (tuple, list)):
        return [_to_json(item) for item in value]
    if isinstance(value, dict):
        return {key: _to_json(item) for key, item in value.items()}
    if isinstance(value, np.generic):
        return value.item()
    return value


def _from_json(kind: Any, value: Any) -> Any:
    """The inverse of `_to_json`, guided by the dataclass's type hints (no code named by the file runs)."""
    if isinstance(value, dict) and set(value) == {"ndarray", "dtype"}:
        dtype = np.dtype(value["dtype"])
        if dtype.hasobject:
            raise ValueError(f"an array of {dtype}")
        return np.asarray(value["ndarray"], dtype)
    if isinstance(kind, type) and dataclasses.is_dataclass(kind):
        if not isinstance(value, dict):
            raise ValueError(f"{kind.__name__}: expected an object")
        hints = typing.get_type_hints(kind)
        return kind(**{field.name: _from_json(hints[field.name], value[field.name]) for field in dataclasses.fields(kind) if field.name in value})
    if typing.get_origin(kind) is tuple and isinstance(value, list):
        return tuple(value)
    if typing.get_origin(kind) is dict:
        if not isinstance(value, dict):
            raise ValueError(f"{kind}: expected an object")
        item = typing.get_args(kind)[1]
        return {name: _from_json(item, entry) for name, entry in value.items()}
    return value


def as_json(value: Any) -> Any:
    """A dataclass (a recording's summary) as JSON-ready values."""
    return dataclasses.asdict(value) if dataclasses.is_dataclass(value) else value
