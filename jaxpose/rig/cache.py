"""A rig project prepared once: every instant of its recordings, kept in one cache folder.

Loading a project (reading every detection, aligning the cameras, undistorting, choosing the person)
is done once; its result, every instant of every recording on one time axis per recording, is written to
``CACHE/prepared-<key>/`` (CACHE: ``PROJECT/.jaxpose_cache``, or --data.cache-dir): one ``.npy`` per
array (``instants.keypoints2d.npy``, ...), written row block by row block as the recordings are prepared
(`Assembly`), and ``project.json`` with the rest (cameras, layout, the per-recording summaries, the
inputs' digests, the sessions of a project without calibration: a `ProjectMeta`; ``recovered.json`` for the rigs
recovered, one per session).  The next run with the same inputs and options
memory-maps the arrays (`read_arrays`): it starts in seconds, and a project larger than memory trains with
only the rows of each batch read from disk.  A split (held-out recordings or fraction, strides) is a
selection of these rows, made after reading (`selected_rows`): training, evaluation, reconstruction and
searches of every split read the same prepared folder.

The key (`entry`, `key`) digests every option that changes the arrays (not the split), the code's `VERSION`, and
each input file's path, size, modification and status-change times (``st_ctime``) and inode, in groups
(the project's own files, a calibration's, each recording's: `input_digests`), the files being those
finding the project found, whatever their names (`_input_files`): a file edited, replaced,
touched or renamed is a miss.  The status-change time is what makes this safe without reading the
files: no tool can set it (``cp -p``, ``rsync -t``, archive extraction and ``os.utime`` keep the
modification time but not it), so a file edited in place to the same size with its time kept is a miss
too.  A copy of the project is a miss once (new inodes and times), never stale.

The folder appears whole or not at all: it is written under a temporary name and renamed.  A prepared
folder is removed only when it can never be read again: when a group of input files it was made from
has changed since, or names a recording that is gone (`commit`, `_prune`); it is renamed away before it
is deleted, and only folders the cache made are looked at.  Folders of other options (another
--data.min-confidence, another subset of recordings) are kept, and the log says how many folders the cache holds and their size.  A
cache that cannot be written (a read-only project without --data.cache-dir) is a warning; the arrays
then stay in memory.

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
import re
import shutil
import struct
import time
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from jaxpose.formats import keypoint_files
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.files import from_typed_json, typed_json
from jaxpose.rig.config import NOT_PREPARED, RigProjectConfig
from jaxpose.rig.recordings import FoundProject, printable
from jaxpose.rig.recovered import RecoveredSession

log = logging.getLogger(__name__)

VERSION = 7  # bump when the prepared arrays change meaning (3: every instant, the split applied after reading; 4: warnings; 5: one recovered rig per session; 6: each recovered rig names its world; 7: a row per (instant, person), the "person" array)
PREFIX = "prepared-"
PART = "instants"  # the prepared arrays' file prefix
SELECTION = "rows-"  # a split's rows, written once inside the prepared folder
RECOVERED_JSON = "recovered.json"
_HEADER_BYTES = 128  # a fixed-length .npy header: the row count is set at the end without moving the data


@dataclasses.dataclass(frozen=True)
class RecordingSummary:
    """What loading did to one recording, for the report (counts over all its instants)."""

    name: str
    cameras: tuple[str, ...]
    """Its cameras, in the prepared project's view order."""
    instants: int
    calibration: str
    """Where its rig comes from (the calibration file, or the session it was recovered for)."""
    offsets: dict[str, int]
    offsets_estimated: bool
    sync_reliable: bool | None
    instants_with_choice: int
    views_without_match: int
    ground_truth_instants: int
    warnings: tuple[str, ...] = ()
    """What reading it found suspect: an unreliable sync and why, a camera sharing no instant with the others."""
    people: tuple[int, ...] = (1,)
    """Its prepared rows of each person (1, 2, ...): one person's are every instant (`jaxpose.rig.tracked`)."""
    implausible_tracks: int = 0
    """Tracks left out as no person (the detector scored them low: `jaxpose.rig.tracked.plausible`)."""
    dropped_person_instants: int = 0
    """Person-instants in tracks left out (too short or implausible)."""


@dataclasses.dataclass(frozen=True)
class SessionSummary:
    """A session of a project without calibration, without its rig (which is kept in ``recovered.json``)."""

    name: str
    recordings: tuple[str, ...]
    reprojection_px: float
    found: str

    @classmethod
    def of(cls, session: RecoveredSession) -> "SessionSummary":
        return cls(session.name, tuple(session.recordings), session.reprojection_px, session.found)

    def with_rig(self, calibration: object) -> RecoveredSession:
        return RecoveredSession(self.name, self.recordings, self.reprojection_px, self.found, calibration)


@dataclasses.dataclass(frozen=True)
class ProjectMeta:
    """What preparing a project found besides its arrays: its folder's ``project.json`` (`typed_json`)."""

    camera_names: tuple[str, ...]
    """Every view, in the prepared arrays' order."""
    layout: str
    """The recordings' keypoint layout."""
    recordings: tuple[RecordingSummary, ...]
    """In the order of their rows."""
    ground_truth_seen: bool
    warnings: tuple[str, ...]
    """What the checks of the calibrations found suspect (people of an unlikely size), for the report."""
    sessions: tuple[SessionSummary, ...]
    """Without a calibration: the sessions whose rigs were recovered."""
    rigs: dict[str, np.ndarray]
    """"K", "R", "t": f32[R, C, 3, 3], [R, C, 3, 3], [R, C, 3] (mm) of the distinct rigs, undistorted (the
    arrays' "rig_index" indexes them)."""
    inputs: dict[str, str] = dataclasses.field(default_factory=dict)
    """The digests of the input files it was made from (`input_digests`; `_prune` reads them)."""

    def __post_init__(self):
        # A project.json of jaxpose before this type holds the rigs as plain nested lists.
        object.__setattr__(self, "rigs", {field: np.asarray(values, np.float32) for field, values in self.rigs.items()})


@dataclasses.dataclass(frozen=True)
class PreparedProject:
    """Every instant of every recording prepared (`jaxpose.rig.project`'s steps 1-7), as the cache holds it:
    the recordings one after the other, each on its time axis in order."""

    meta: ProjectMeta
    arrays: Mapping[str, np.ndarray]
    """Per instant: keypoints2d, confidence, rig_index, subject, recording, frame, and target3d where some
    recording has ground truth; memory-mapped from the cache, or in memory."""
    sessions: tuple[RecoveredSession, ...]
    """Without a calibration: the sessions and the rig recovered from each."""
    folder: Path | None
    """The prepared folder in the cache (None: prepared in memory)."""
    how: str
    """How the arrays were had: read from the cache, prepared and cached, or prepared in memory."""


@dataclasses.dataclass(frozen=True)
class Entry:
    """Where one project's prepared arrays are kept in its cache (`entry`), and what they are keyed by."""

    cache: Path
    """The cache folder (`jaxpose.rig.config.RigProjectConfig.cache`)."""
    key: str
    inputs: Mapping[str, str]
    """The digest of each group of input files (`input_digests`), kept in project.json (`_prune` reads them)."""
    auto_key: str | None
    """With a layout named (as a run records the one --data.skeleton auto resolved): the key of the same
    project prepared with auto, which serves where it resolved to that layout (`lookup`)."""
    layout: str


def entry(config: RigProjectConfig, found: FoundProject) -> Entry:
    """The cache entry of a project's settings and files as found."""
    inputs = input_digests(_input_files(config, found))
    auto = None if config.skeleton == "auto" else key(_options(dataclasses.replace(config, skeleton="auto")), inputs)
    return Entry(config.cache, key(_options(config), inputs), inputs, auto, config.skeleton)


def _options(config: RigProjectConfig) -> dict:
    """Every option that changes the prepared arrays (not where the project and its cache are, not the
    split), and the version of the JSON parsing whose results they hold."""
    options = {field.name: getattr(config, field.name) for field in dataclasses.fields(config) if field.name not in NOT_PREPARED}
    options["calibration"] = None if config.calibration is None else str(config.calibration.resolve())
    return options | {"parsed_frames": keypoint_files.CACHE_VERSION}


def _input_files(config: RigProjectConfig, found: FoundProject) -> dict[str, list[Path]]:
    """Every file loading reads, by group (`input_digests`), taken from what `find_project` found whatever its
    name (a calibration named ``.calibration.toml`` too): the project folder's files with the calibration
    found there, or --data.calibration in a group of its own; each recording's folder's files with its own
    calibration and every camera's detections.  A calibration comes with its siblings of the same kind
    (EasyMocap's intri.yml beside extri.yml, the files of a calibration folder); a folder's other files are
    there too, as a later run may find one (a new calibration, a ground truth)."""

    def plain_files(folder: Path, suffix: str = "") -> list[Path]:
        return [entry for entry in folder.iterdir() if not entry.name.startswith(".") and entry.suffix.endswith(suffix) and not entry.is_dir()]

    def calibration_files(path: Path | None) -> list[Path]:
        if path is None:
            return []
        return [path, *(plain_files(path) if path.is_dir() else plain_files(path.parent, path.suffix))]

    project = f"project {config.root.resolve()}"
    groups = {project: plain_files(config.root)}
    given = None if config.calibration is None else f"calibration {config.calibration.resolve()}"
    groups.setdefault(given or project, []).extend(calibration_files(found.calibration))
    for recording in found.recordings:
        files = plain_files(recording.folder) + calibration_files(recording.calibration)
        for source in recording.sources.values():
            files += plain_files(source, ".json") if source.is_dir() else [source]
        groups[f"recording {recording.folder.resolve()}"] = files
    return groups


def lookup(entry: Entry) -> PreparedProject | None:
    """The prepared project of `entry`, memory-mapped (or, with a layout named, what auto prepared where it
    resolved to that layout); None where the cache holds neither."""
    return _read(entry.cache, entry.key) or (None if entry.auto_key is None else _read(entry.cache, entry.auto_key, entry.layout))


def _read(cache: Path, cache_key: str, layout: str | None = None) -> PreparedProject | None:
    """The prepared project of `cache_key` in the cache folder `cache` (of the keypoint layout `layout`, where
    given); None where there is none.  An unreadable one is removed with a warning (it is jaxpose's own
    folder, and only a missed shortcut)."""
    started = time.perf_counter()
    prepared = folder(cache, cache_key)
    if not prepared.is_dir():
        return None
    try:
        written, recovered = read_meta(prepared, _recovered_type(prepared))
        meta = from_typed_json(ProjectMeta, written)
        arrays = read_arrays(prepared)
        sessions = tuple(session.with_rig(recovered[session.name]) for session in meta.sessions)
    except Exception as error:  # noqa: BLE001 - an unreadable cache is only a missed shortcut
        log.warning("ignoring the unreadable prepared project %s (%s: %s); preparing it again", prepared, type(error).__name__, error)
        _remove(prepared)
        return None
    if layout is not None and meta.layout != layout:
        return None
    log.info("prepared project read from the cache %s in %.1f s (%d recordings, %d instants); %s", prepared,
             time.perf_counter() - started, len(meta.recordings), len(arrays["frame"]), size_note(cache))  # fmt: skip
    return PreparedProject(meta, arrays, sessions, prepared, f"read from the cache {prepared}")


def _recovered_type(prepared: Path) -> object | None:
    """The type the cached recovered rigs decode to (session -> `Calibration`: the calibrate extra recovered
    them), or None without them."""
    if not (prepared / RECOVERED_JSON).exists():
        return None
    from jaxpose.calibration import Calibration

    return dict[str, Calibration]


def input_digests(groups: Mapping[str, Iterable[Path]]) -> dict[str, str]:
    """{group: the digest of its files' paths, sizes, modification and status-change times and inodes}."""
    digests = {}
    for group, files in groups.items():
        digest = hashlib.blake2b(digest_size=16)
        for path in sorted(set(files)):
            try:
                status = os.stat(path)  # follows links: the content's file
            except OSError as error:
                found = "a symbolic link that loops" if error.errno == errno.ELOOP else f"a file that cannot be read ({error.strerror})"
                raise DataFormatError(printable(path), "a readable input file", found) from None
            digest.update(os.fsencode(path) + b"\0")
            digest.update(struct.pack("<5q", status.st_size, status.st_mtime_ns, status.st_ctime_ns, status.st_ino, status.st_dev))
        digests[group] = digest.hexdigest()
    return digests


def key(options: Mapping[str, Any], inputs: Mapping[str, str]) -> str:
    """The cache key of `options` (every option that changes the prepared arrays, by name) and the `inputs`
    (`input_digests`)."""
    digest = hashlib.blake2b(digest_size=16)
    digest.update(json.dumps({"version": VERSION, **options, "inputs": dict(inputs)}, sort_keys=True, default=str).encode())
    return digest.hexdigest()


def folder(cache: Path, cache_key: str) -> Path:
    return cache / f"{PREFIX}{cache_key}"


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
    """The prepared arrays, appended recording by recording: into growing .npy files ``instants.<name>.npy``
    (`PART`) in `directory`, or in memory where `directory` is None.  An array that a later recording starts
    (a ground truth) is filled with NaN for the rows before it."""

    def __init__(self, directory: Path | None):
        self.directory = directory
        self.files: dict[str, _GrowingNpy | list[np.ndarray]] = {}
        self.rows = 0

    def add(self, arrays: Mapping[str, np.ndarray | None]) -> None:
        count = len(next(iter(arrays.values())))
        for name, array in arrays.items():
            if array is None:
                if name in self.files:
                    self._write(name, np.full((count, *self._row_shape(name)), np.nan, np.float32))
                continue
            if name not in self.files and self.rows:
                self._write(name, np.full((self.rows, *array.shape[1:]), np.nan, array.dtype))
            self._write(name, array)
        self.rows += count

    def _row_shape(self, name: str) -> tuple[int, ...]:
        target = self.files[name]
        return target.row_shape if isinstance(target, _GrowingNpy) else target[0].shape[1:]

    def _write(self, name: str, array: np.ndarray) -> None:
        if name not in self.files:
            self.files[name] = [] if self.directory is None else _GrowingNpy(self.directory / f"{PART}.{name}.npy", array)
        self.files[name].append(array)

    def close(self) -> dict[str, np.ndarray] | None:
        """The files closed (read them with `read_arrays`), or in memory {name: array}."""
        if self.directory is not None:
            for target in self.files.values():
                target.close()
            return None
        return {name: np.concatenate(pieces) for name, pieces in self.files.items()}


def read_arrays(directory: Path) -> dict[str, np.ndarray]:
    """{name: memory-mapped array} of a prepared folder."""
    return {path.name[len(PART) + 1 : -len(".npy")]: np.load(path, mmap_mode="r", allow_pickle=False) for path in sorted(directory.glob(f"{PART}.*.npy"))}


def start(entry: Entry) -> Path | None:
    """A fresh temporary folder to prepare `entry` into (None, with a warning, where its cache cannot be written)."""
    cache, cache_key = entry.cache, entry.key
    try:
        cache.mkdir(parents=True, exist_ok=True)
        _remove_interrupted(cache, PREFIX)
        temporary = cache / f"{PREFIX}{cache_key}.tmp-{os.getpid()}"
        shutil.rmtree(temporary, ignore_errors=True)
        temporary.mkdir()
        return temporary
    except (OSError, ValueError) as error:
        log.warning("the prepared project is not cached (%s cannot be written: %s; --data.cache-dir names a folder that can);"
                    " it stays in memory", cache, error)
        return None


def _remove_interrupted(folder: Path, prefix: str) -> None:
    """Remove the temporary folders `prefix`*.tmp-PID in `folder` of runs that were interrupted."""
    for stale in folder.glob(f"{prefix}*.tmp-*"):
        pid = int(stale.name.rsplit("-", 1)[1])
        if not _alive(pid):
            shutil.rmtree(stale, ignore_errors=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    return True


def finish(entry: Entry, temporary: Path | None, assembly: Assembly, meta: ProjectMeta,
           sessions: tuple[RecoveredSession, ...]) -> PreparedProject:  # fmt: skip
    """The prepared project whose arrays `assembly` holds: committed to the cache as `entry` (with its inputs'
    digests in `meta`) and memory-mapped from it, or in memory where the cache cannot be written (`temporary` None)."""
    in_memory = assembly.close()
    meta = dataclasses.replace(meta, inputs=dict(entry.inputs))
    if temporary is None:
        return PreparedProject(meta, in_memory, sessions, None, f"prepared in memory ({entry.cache} cannot be written: not cached)")
    final = commit(temporary, entry.key, typed_json(meta), {session.name: session.calibration for session in sessions} or None)
    return PreparedProject(meta, read_arrays(final), sessions, final, f"prepared and written to the cache {final}")


def commit(temporary: Path, cache_key: str, meta: Mapping[str, Any], recovered: object | None) -> Path:
    """Write the metadata (`meta`: project.json's JSON, a `ProjectMeta` as `typed_json`), then move the folder to its final name (another process's finished folder
    of the same key wins); prepared folders made from inputs that have changed since are removed."""
    (temporary / "project.json").write_text(json.dumps(meta, indent=1))
    if recovered is not None:
        (temporary / RECOVERED_JSON).write_text(json.dumps(typed_json(recovered)))
    final = temporary.parent / f"{PREFIX}{cache_key}"
    try:
        os.rename(temporary, final)
    except OSError:  # the same key finished meanwhile: keep that one
        shutil.rmtree(temporary, ignore_errors=True)
    _prune(final, meta.get("inputs", {}))
    return final


def _prune(kept: Path, inputs: Mapping[str, str]) -> None:
    """Remove the prepared folders beside `kept` that no run can read again: those made from a group of input
    files (`input_digests`) whose digest is now another, those of this project made from a recording (or a
    calibration) that is gone, and those of an earlier jaxpose (no digests: their `VERSION` is in no key
    made now).  Only the cache's own folders are looked at (`_made_from`); folders of other options, or of
    recordings that are there but left out by --data.recordings, stay."""
    projects = {group for group in inputs if group.startswith("project ")}
    for other in kept.parent.glob(f"{PREFIX}*"):
        made_from = _made_from(other)
        if other == kept or made_from is None:
            continue
        if made_from is _EARLIER:
            changed = ["an earlier version of jaxpose"]
        else:
            changed = sorted(group for group, digest in made_from.items() if group in inputs and inputs[group] != digest)
            if projects & set(made_from):  # this project's: a group of a path that is gone never comes back
                changed += sorted(f"{group} (gone)" for group in made_from if group not in inputs and not os.path.exists(group.partition(" ")[2]))
        if changed:
            log.info("removing the prepared project %s: made from inputs that have changed since (%s)", other, ", ".join(changed)[:200])
            _remove(other)


_EARLIER: Mapping[str, str] = {}
_KEY_NAME = re.compile(re.escape(PREFIX) + "[0-9a-f]{32}")


def _made_from(prepared: Path) -> Mapping[str, str] | None:
    """The input digests a prepared folder was made from (`_EARLIER` for one of an earlier jaxpose); None for
    what the cache did not make, which is never removed: a folder named otherwise than `folder` names it (a
    user's, in a shared --data.cache-dir; one being written), a link, or one without jaxpose's project.json."""
    if not _KEY_NAME.fullmatch(prepared.name) or prepared.is_symlink() or not prepared.is_dir():
        return None
    try:
        meta = json.loads((prepared / "project.json").read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(meta, dict) or "layout" not in meta:
        return None
    return meta.get("inputs", _EARLIER)


def _remove(prepared: Path) -> None:
    """Delete a prepared folder so that a run reading the cache meanwhile finds it whole or not at all: it is
    renamed to a temporary name first (atomic; a second run removing it too finds nothing to rename), then
    deleted; a deletion cut short is finished by a later `start` (`_remove_interrupted`)."""
    doomed = prepared.with_name(f"{prepared.name}.tmp-{os.getpid()}")
    try:
        os.rename(prepared, doomed)
    except OSError:
        return
    shutil.rmtree(doomed, ignore_errors=True)


def size_note(cache: Path) -> str:
    """How many prepared folders `cache` holds and the size of everything in it, for the log."""
    total = 0
    for directory, _, files in os.walk(cache):
        for name in files:
            try:
                total += os.stat(os.path.join(directory, name)).st_blocks * 512  # on disk: a growing file's holes are free
            except OSError:
                pass
    prepared = sum(1 for path in cache.glob(f"{PREFIX}*") if ".tmp-" not in path.name)
    return f"the cache {cache} holds {prepared} prepared project(s), {total / 2**20:,.1f} MiB in all (delete it to free the space)"


def selected_rows(directory: Path | None, part: str, arrays: Mapping[str, np.ndarray], rows: np.ndarray) -> dict[str, np.ndarray]:
    """The rows `rows` (int, increasing) of every prepared array: the arrays themselves for every row; in
    a prepared folder `directory`, written once to ``rows-<part>-<digest>/<part>.<name>.npy`` and memory-mapped
    (a later run of the same split reads them, a project larger than memory stays on disk, and the
    pseudo-labels are kept beside them); in memory otherwise (or where the folder cannot be written)."""
    total = len(next(iter(arrays.values())))
    if len(rows) == total and np.array_equal(rows, np.arange(total)):
        return dict(arrays)
    if directory is None or not len(rows):
        return {name: np.asarray(array[rows]) for name, array in arrays.items()}
    digest = hashlib.blake2b(np.ascontiguousarray(rows, np.int64).tobytes(), digest_size=12).hexdigest()
    selection = directory / f"{SELECTION}{part}-{digest}"
    if not selection.is_dir():
        temporary = directory / f"{selection.name}.tmp-{os.getpid()}"
        try:
            _remove_interrupted(directory, SELECTION)
            temporary.mkdir(exist_ok=True)
            for name, array in arrays.items():
                out = np.lib.format.open_memmap(temporary / f"{part}.{name}.npy", mode="w+", dtype=array.dtype, shape=(len(rows), *array.shape[1:]))
                for start in range(0, len(rows), _COPY_ROWS):  # bounded memory
                    out[start : start + _COPY_ROWS] = array[rows[start : start + _COPY_ROWS]]
                out.flush()
                del out
            try:
                os.rename(temporary, selection)  # whole or not at all
            except OSError:  # another process's finished folder of the same rows: keep that one
                shutil.rmtree(temporary, ignore_errors=True)
        except OSError as error:
            shutil.rmtree(temporary, ignore_errors=True)
            log.warning("the %s rows are not cached (%s: %s): they stay in memory", part, selection, error)
            return {name: np.asarray(array[rows]) for name, array in arrays.items()}
    return {name: np.load(selection / f"{part}.{name}.npy", mmap_mode="r", allow_pickle=False) for name in arrays}


_COPY_ROWS = 65536


def read_meta(directory: Path, recovered_type: type | None = None) -> tuple[dict[str, Any], object | None]:
    """(project.json's JSON, the recovered calibration as a `recovered_type` or None) of a prepared folder.  A file that does not decode is a `DataFormatError` naming it."""
    meta = json.loads((directory / "project.json").read_text())
    recovered = None
    path = directory / RECOVERED_JSON
    if recovered_type is not None and path.exists():
        try:
            recovered = from_typed_json(recovered_type, json.loads(path.read_text()))
        except (ValueError, TypeError, KeyError) as error:
            raise DataFormatError(printable(path), f"a recovered rig written by jaxpose (delete the folder {directory} to prepare again)", str(error)) from None
    return meta, recovered
