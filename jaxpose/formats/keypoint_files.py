"""Per-camera 2D detection files: OpenPose-style JSON frame folders and COCO keypoint-results files.

Users bring, for each camera of a recording, either

- a folder of OpenPose-style JSON frames, one file per frame: ``{"version": ..., "people": [{"person_id":
  [-1], "pose_keypoints_2d": [x, y, score] * J, "face_keypoints_2d": ..., ...}, ...]}``, pretty-printed or
  compact.  Only ``pose_keypoints_2d`` is read; an entry whose list is empty is a person not found in that
  frame, left out.  J is 25 (BODY_25 or BODY_25B: the count cannot tell them
  apart), 26 (HALPE_26), 17 (COCO-17) or 18 (OpenPose COCO-18); every file of a folder must have the same J.
  The frame number is the last run of digits of the file name once ``_keypoints.json`` / ``.json`` is
  removed (``clip_000000000123_keypoints.json``, ``cam01.0010.json``, ``frame_00001.json``); files that
  are not ``.json`` (or whose name starts with a dot) are ignored; or
- one COCO keypoint-results file: a list of ``{"image_id", "keypoints": [x, y, score] * J, ...}``, several
  entries with one image_id being several people in that frame.  ``image_id`` is the frame number, or a
  file-name string (AlphaPose: ``"out-002.jpg"``) whose last run of digits (extension removed) is.

Both become a `CameraDetections`: every person of every frame in the detector's own joint order, frames
sorted, padded to the most people in any frame.  A joint written as undetected (0, 0, 0), or with a
non-finite value, is stored as 0, 0 with score 0; scores follow `jaxpose.formats.confidences` (a negative
one refused, those above 1 clipped to 1 and counted).  Malformed input raises `DataFormatError` naming the
file and the field, before anything is returned.

Folders of many files are parsed by a process pool (`read_openpose_folder`), with orjson when it is
importable (`jaxpose.formats.fast_json`); COCO files by `jaxpose.formats.coco_results`.  The results of
`read_camera_detections` are cached in the file its caller names (a rig project's cache; never beside the
input: a user's folders are only read), keyed by the input files' names and contents (`file_cache`); see
benchmarks/README.md for the speeds.
"""

from __future__ import annotations

import dataclasses
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from jaxpose.formats import coco_results, confidences, fast_json, file_cache, file_pool
from jaxpose.formats.errors import DataFormatError, printable
from jaxpose.formats.frame_numbers import check_frame_numbers, frame_number, image_frame_number

CACHE_VERSION = 2
"""Part of every cache key (`jaxpose.formats.file_cache`): bump it when the cached arrays change meaning
(2: scores clipped to 1, their count cached)."""
CACHED_FIELDS = ("frames", "keypoints", "scores", "people", "clipped_scores")

_FRAME_EXPECTED = 'an OpenPose JSON frame {"people": [{"pose_keypoints_2d": [x, y, score, ...]}, ...]}'


@dataclasses.dataclass(frozen=True)
class CameraDetections:
    """Every person detected in every frame of one camera, in the detector's own joint order."""

    frames: np.ndarray
    """int64[F] frame numbers, sorted ascending, unique (frames whose file lists nobody are kept, with 0 people)."""
    keypoints: np.ndarray
    """float32[F, P, J, 2] pixels; P = the most people in any frame; padding rows are 0."""
    scores: np.ndarray
    """float32[F, P, J] detector scores in [0, 1] (`jaxpose.formats.confidences`), 0 for padding / undetected."""
    people: np.ndarray
    """int32[F] number of people in each frame."""
    source: str
    """The folder or file read."""
    clipped_scores: int = 0
    """How many scores of the file(s) were above 1, clipped to 1 (`jaxpose.formats.confidences`)."""

    @property
    def values_per_person(self) -> int:
        """3 * J: the length of one person's [x, y, score] list, for skeleton inference by the caller."""
        return 3 * self.keypoints.shape[2]


def frame_files(path: str | Path) -> list[tuple[int, str]]:
    """The frame files of OpenPose output as (frame number, path), sorted by frame number: the ``.json``
    files of a folder, or one frame file, whose frame number is that of its name (0 without digits).

    In a folder, files that are not ``.json``, and hidden files (name starting with a dot), are ignored.
    Two files with one frame number, or a name without digits, raise `DataFormatError` naming the files.
    """
    path = Path(path)
    if path.is_file():
        return [(frame_number(path.name) if re.search(r"\d", path.name) else 0, str(path))]
    return [(frame, entry.path) for frame, entry in _numbered(path, _json_entries(path))]


def _json_entries(folder: Path) -> list[os.DirEntry]:
    if not folder.is_dir():
        found = "a file" if folder.exists() else "nothing there"
        raise DataFormatError(folder, "a folder of OpenPose JSON frames (one .json file per frame)", found)
    with os.scandir(folder) as listing:
        entries = [e for e in listing if e.name.endswith(".json") and not e.name.startswith(".") and e.is_file()]
    if not entries:
        raise DataFormatError(folder, "OpenPose JSON frames (*.json files)", "no .json file")
    for entry in entries:  # a name in another encoding would reach the outputs' image ids undecodable
        if printable(entry.name) != entry.name:
            found = f"the file '{printable(entry.name)}' (undecodable bytes as \\xNN)"
            raise DataFormatError(folder, "frame file names in UTF-8 (rename the file, e.g. with convmv)", found)
    return entries


def _numbered(folder: Path, entries: list[os.DirEntry]) -> list[tuple[int, os.DirEntry]]:
    numbered = []
    for entry in entries:
        try:
            numbered.append((frame_number(entry.name), entry))
        except DataFormatError as error:
            raise DataFormatError(entry.path, error.expected, error.found) from None
    numbered.sort(key=lambda item: item[0])
    for (frame, entry), (next_frame, next_entry) in zip(numbered, numbered[1:]):
        if frame == next_frame:
            raise DataFormatError(
                folder, "one file per frame number", f"{entry.name} and {next_entry.name} both have frame number {frame}"
            )
    return numbered


# ---------------------------------------------------------------------------------------------
# Parsing (pure functions of file contents; the pool runs `_parse_chunk`)


def _person_values(person: Any, index: int) -> list:
    """One person's ``pose_keypoints_2d`` list; raises _FieldError with the reason."""
    field = f"people[{index}].pose_keypoints_2d"
    if not isinstance(person, dict):
        raise _FieldError(field, f"people[{index}] is a {type(person).__name__}, not an object")
    values = person.get("pose_keypoints_2d")
    if not isinstance(values, list):
        raise _FieldError(field, f"no 'pose_keypoints_2d' list (keys: {sorted(person)})")
    if len(values) % 3:
        raise _FieldError(field, f"{len(values)} values, not a multiple of 3")
    return values


class _FieldError(Exception):
    def __init__(self, field: str, found: str):
        super().__init__(field, found)
        self.field, self.found = field, found


def _parse_chunk(paths: Sequence[str]) -> tuple:
    """Parse OpenPose frames: ("ok", people int32[n], lengths int32[persons], values f32[sum(lengths)],
    each file's `file_cache.content_digest`) or ("error", where, expected, found) for the first bad file
    (DataFormatError does not pickle)."""
    people, lengths, flat, digests = [], [], [], []
    for path in paths:
        try:
            with open(path, "rb") as file:
                data = file.read()
        except OSError as error:
            return "error", path, "a readable OpenPose JSON frame", f"{type(error).__name__}: {error.strerror}"
        digests.append(file_cache.content_digest(data))
        try:
            frame = fast_json.loads(data)
        except ValueError as error:  # json.JSONDecodeError and UnicodeDecodeError are ValueErrors
            return "error", path, _FRAME_EXPECTED, f"invalid JSON: {error}"
        if not isinstance(frame, dict) or not isinstance(frame.get("people"), list):
            found = f"a JSON {type(frame).__name__}" if not isinstance(frame, dict) else (
                f"no 'people' list (keys: {sorted(frame)})")  # fmt: skip
            return "error", path, _FRAME_EXPECTED, found
        count = 0
        try:
            for index, person in enumerate(frame["people"]):
                values = _person_values(person, index)
                if values:  # an empty list is a person OpenPose lists but did not find (Pose2Sim writes them)
                    lengths.append(len(values))
                    flat.extend(values)
                    count += 1
        except _FieldError as error:
            return "error", path, f"{_FRAME_EXPECTED} (field {error.field})", error.found
        people.append(count)
    try:
        values = np.array(flat, np.float32)
        if values.ndim != 1:
            raise ValueError("nested lists")
    except (TypeError, ValueError):
        return _first_non_numeric(paths)
    return "ok", np.array(people, np.int32), np.array(lengths, np.int32), values, digests


def _digest_chunk(paths: Sequence[str]) -> tuple:
    """("ok", each file's `file_cache.content_digest`) or ("error", where, expected, found), as `_parse_chunk`."""
    try:
        return "ok", [file_cache.file_digest(path) for path in paths]
    except OSError as error:
        return "error", error.filename, "a readable OpenPose JSON frame", f"{type(error).__name__}: {error.strerror}"


def _first_non_numeric(paths: Sequence[str]) -> tuple:
    """The error of the first file whose keypoints are not all numbers (the slow path of a bad chunk)."""
    for path in paths:
        with open(path, "rb") as file:
            frame = fast_json.loads(file.read())
        for index, person in enumerate(frame["people"]):
            bad = [v for v in person["pose_keypoints_2d"] if v is not None and not isinstance(v, int | float)]
            if bad:
                return "error", path, f"numbers in people[{index}].pose_keypoints_2d", f"{bad[0]!r}"
    raise AssertionError("a chunk failed to convert but every file holds numbers")  # pragma: no cover


def _assemble(
    frames: np.ndarray, people: np.ndarray, lengths: np.ndarray, values: np.ndarray, source: str, owners: Sequence[str]
) -> CameraDetections:
    """CameraDetections from per-frame counts and the persons' flat [x, y, score] lists, in frame order.

    `owners[k]` names where frame k came from (a file, an image_id), for the errors of persons of
    different lengths and of negative scores; scores go through `jaxpose.formats.confidences`.
    """
    check_frame_numbers(frames, source, owners)
    if len(lengths) and (lengths != lengths[0]).any():
        raise _length_error(people, lengths, source, owners)
    per_person = int(lengths[0]) if len(lengths) else 0
    joints = per_person // 3
    rows = values.reshape(len(lengths), joints, 3)
    rows = np.where(np.isfinite(rows).all(-1, keepdims=True), rows, np.float32(0))
    frame_of = np.repeat(np.arange(len(frames)), people)
    slot = np.arange(len(lengths)) - np.repeat(np.cumsum(people) - people, people)

    def locate(index: tuple[int, ...]) -> tuple[str, str]:
        person, joint = index
        return source, f"{owners[frame_of[person]]} (frame {frames[frame_of[person]]}), person {slot[person]}, joint {joint}"

    scores, clipped = confidences.normalise_scores(rows[..., 2], locate)
    most = int(people.max()) if len(people) else 0
    keypoints = np.zeros((len(frames), most, joints, 2), np.float32)
    padded = np.zeros((len(frames), most, joints), np.float32)
    keypoints[frame_of, slot] = rows[..., :2]
    padded[frame_of, slot] = scores
    return CameraDetections(np.asarray(frames, np.int64), keypoints, padded, people.astype(np.int32), source, clipped)


def _length_error(people: np.ndarray, lengths: np.ndarray, source: str, owners: Sequence[str]) -> DataFormatError:
    frame_of = np.repeat(np.arange(len(people)), people)
    by_length: dict[int, list[str]] = {}
    for length in dict.fromkeys(lengths.tolist()):
        by_length[length] = list(dict.fromkeys(owners[k] for k in frame_of[lengths == length]))
    first = int(lengths[0])
    other = next(length for length in by_length if length != first)

    def listed(names: list[str]) -> str:
        shown = ", ".join(names[:3])
        return shown + (f" and {len(names) - 3} more" if len(names) > 3 else "")

    counts = "; ".join(
        f"{length} values ({length // 3} joints) in {len(names)} file(s): {listed(names)}"
        for length, names in by_length.items()
    )
    return DataFormatError(
        by_length[other][0],
        f"pose_keypoints_2d with the same number of values in every person of every file ({first} as in "
        f"{by_length[first][0]})",
        f"{other} values; of {source}: {counts}",
    )


# ---------------------------------------------------------------------------------------------
# OpenPose folders


def read_openpose_folder(folder: str | Path, progress: bool = True, workers: int | None = None) -> CameraDetections:
    """Read an OpenPose-style folder of per-frame JSON files (or one such file) as `CameraDetections`."""
    return read_openpose_frames(frame_files(folder), str(folder), progress, workers)


def read_openpose_frames(
    files: Sequence[tuple[int, str]], source: str, progress: bool = True, workers: int | None = None
) -> CameraDetections:
    """The OpenPose frame files `files`, (frame number, path) in frame order as `frame_files` lists them,
    as `CameraDetections` of `source`.

    `workers` processes parse them (`jaxpose.formats.file_pool`: default ``os.cpu_count()``, one process
    where a pool does not pay).  `progress` shows a tqdm bar for long reads.
    """
    return _read_frames(files, source, progress, workers)[0]


def _read_frames(
    files: Sequence[tuple[int, str]], source: str, progress: bool, workers: int | None
) -> tuple[CameraDetections, list[bytes]]:
    """`read_openpose_frames`, and each file's `file_cache.content_digest` (of the bytes it parsed)."""
    paths = [path for _, path in files]
    parts = file_pool.map_chunks(_parse_chunk, paths, f"reading {Path(source).name}", progress, workers)
    people, lengths, values = (np.concatenate(column) for column in list(zip(*parts))[:3])
    owners = [os.path.basename(p) for p in paths]
    detections = _assemble(np.array([frame for frame, _ in files], np.int64), people, lengths, values, source, owners)
    return detections, [digest for part in parts for digest in part[3]]


# ---------------------------------------------------------------------------------------------
# COCO keypoint results


def read_coco_results(path: str | Path) -> CameraDetections:
    """Read a COCO keypoint-results file as `CameraDetections`: entries grouped by frame, in file order."""
    image_ids, keypoints = coco_results.load_coco_entries(path)
    numbers: dict[Any, int] = {}
    named: dict[int, Any] = {}
    for image_id in dict.fromkeys(image_ids):
        try:
            number = image_frame_number(image_id)
        except DataFormatError as error:
            raise DataFormatError(path, "image_id an integer or a string with a frame number", error.where) from None
        if number in named:
            raise DataFormatError(
                path, "one image_id per frame number", f"image ids {named[number]!r} and {image_id!r} are both frame {number}"
            )
        numbers[image_id], named[number] = number, image_id
    frame_of_entry = np.array([numbers[i] for i in image_ids], np.int64)
    order = np.argsort(frame_of_entry, kind="stable")
    frames, people = np.unique(frame_of_entry, return_counts=True)
    values = keypoints[order].reshape(-1)
    lengths = np.full(len(image_ids), keypoints.shape[1] * 3, np.int32)
    owners = [f"image_id {named[frame]!r}" for frame in frames.tolist()]
    return _assemble(frames, people.astype(np.int32), lengths, values, str(path), owners)


# ---------------------------------------------------------------------------------------------
# Dispatch and cache (`jaxpose.formats.file_cache`)


def read_camera_detections(path: str | Path, progress: bool = True, cache: Path | None = None) -> CameraDetections:
    """One camera's detections: a folder -> OpenPose frames, a ``.json`` file -> COCO results (or, when
    the file holds one JSON object, a single OpenPose frame).

    `cache`: the file the arrays are kept in (e.g. in a rig project's cache), reused while no input file was
    added, removed, renamed or changed in content (`jaxpose.formats.file_cache`: the files are hashed where
    a cache exists, and as they are parsed where none does); a corrupt or unwritable cache is ignored with a
    warning.  None: parsed every time, nothing written.
    """
    path = Path(path)
    if path.is_dir():
        listing = _json_entries(path)

        def digests() -> list[tuple[str, bytes]]:
            paths = [entry.path for entry in listing]
            parts = file_pool.map_chunks(_digest_chunk, paths, f"checking {path.name}", progress, None)
            return list(zip((entry.name for entry in listing), (digest for part in parts for digest in part[0])))

        def parse() -> tuple[CameraDetections, list[tuple[str, bytes]]]:
            files = [(frame, entry.path) for frame, entry in _numbered(path, listing)]
            detections, contents = _read_frames(files, str(path), progress, None)
            return detections, list(zip((os.path.basename(file) for _, file in files), contents))

    elif path.is_file() and path.suffix == ".json":

        def digests() -> list[tuple[str, bytes]]:
            return [(path.name, file_cache.file_digest(path))]

        def parse() -> tuple[CameraDetections, list[tuple[str, bytes]]]:
            contents = digests()  # read before parsing: a file changed meanwhile is read again next time
            return (read_openpose_folder(path) if is_openpose_frame_file(path) else read_coco_results(path)), contents

    else:
        found = "nothing there" if not path.exists() else f"a {path.suffix or 'suffix-less'} file"
        raise DataFormatError(path, "a folder of OpenPose JSON frames or a COCO keypoint-results .json file", found)
    if cache is None:
        return parse()[0]
    label = f"jaxpose keypoint cache v{CACHE_VERSION}"
    cache = Path(cache)
    if cache.exists():
        key = file_cache.cache_key(label, digests())
        cached = file_cache.load(cache, key, str(path), lambda arrays: _from_arrays(arrays, str(path)))
        if cached is not None:
            return cached
    detections, contents = parse()
    arrays = {field: np.asarray(getattr(detections, field)) for field in CACHED_FIELDS}
    file_cache.save(cache, file_cache.cache_key(label, contents), detections.source, arrays)
    return detections


def is_openpose_frame_file(path: str | Path) -> bool:
    """Whether a ``.json`` file holds one JSON object (an OpenPose frame) rather than a list (COCO results)."""
    with open(path, "rb") as file:
        start = file.read(4096).lstrip(b"\xef\xbb\xbf \t\r\n")
    return start.startswith(b"{")


def _from_arrays(arrays, source: str) -> CameraDetections:
    """The detections of a cache's arrays; a ValueError where their shapes disagree."""
    detections = CameraDetections(
        np.asarray(arrays["frames"], np.int64), np.asarray(arrays["keypoints"], np.float32),
        np.asarray(arrays["scores"], np.float32), np.asarray(arrays["people"], np.int32), source,
        int(arrays["clipped_scores"]),
    )  # fmt: skip
    frames, people = len(detections.frames), detections.keypoints.shape[1]
    if (detections.scores.shape != detections.keypoints.shape[:3] or detections.keypoints.shape[-1] != 2
            or detections.people.shape != (frames,) or (detections.people > people).any()):  # fmt: skip
        raise ValueError(f"inconsistent shapes {detections.keypoints.shape}, {detections.scores.shape}")
    return detections
