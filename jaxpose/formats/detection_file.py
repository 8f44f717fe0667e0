"""A file of detected 2D poses to lift one at a time (`jaxpose.predict`'s input), laid out a pose per row.

The kind is told by the path:
- OpenPose output: a folder of per-frame ``.json`` files (``--write_json``; also Pose2Sim's
  ``cam01.0010.json`` and ``frame_00001.json``), or one such file (``*_keypoints.json``, or a ``.json``
  file holding one object).  Every person's ``pose_keypoints_2d`` is one pose, frames in frame-number
  order, the image id the file name without ``_keypoints.json`` (or ``.json``);
- COCO keypoint results: a ``.json`` list of {"image_id", "keypoints": [x, y, score] * J, ...}, one pose
  per entry, in file order, the image ids as written (AlphaPose's file names too);
- ``.npz`` with ``keypoints`` [N, J, 2] px and optionally ``confidence`` [N, J], ``image_id`` [N] and
  ``K`` [N, 3, 3] (one camera per pose).

Every pose has a frame number, the time axis of the outputs: an OpenPose file's index (the last digits of
its name, `jaxpose.formats.frame_numbers.frame_number`), else its image id's (`image_frame_number`: an
integer itself, a file name's last digits).  Where some image id has no digits, or two ids share a number,
the frames are numbered 0, 1, ... in sequence order (`sequence_order`) and `frames_note` says so.

The JSON files are parsed by `jaxpose.formats.keypoint_files` and `coco_results`, one parser per format; this
module only lays their poses out a row each.  Which joint layout the keypoints are in is the reader's
caller's to decide (`jaxpose.layouts`): a detector's JSON says it by its keypoint count alone, an
``.npz`` not at all.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any, Literal

import numpy as np

from jaxpose.formats import coco_results, confidences, keypoint_files
from jaxpose.formats.frame_numbers import OPENPOSE_SUFFIX, frame_stem, image_frame_number
from jaxpose.formats.errors import DataFormatError


@dataclasses.dataclass(frozen=True)
class DetectionFile:
    """Poses read from an input file, in the file's joint layout."""

    kind: Literal["openpose", "coco", "npz"]
    """What was read: OpenPose JSON, COCO keypoint results, or an .npz."""
    source: Path
    """The file or folder read."""
    keypoints: np.ndarray
    """f32[N, J, 2] pixels."""
    scores: np.ndarray | None
    """f32[N, J] detector scores, or None (all detected)."""
    image_ids: list[Any]
    """One per pose (int or str), kept in the output."""
    frames: np.ndarray
    """int64[N] the frame number of each pose (see the module docstring)."""
    first_frame: int
    """The sequence's first frame: an OpenPose folder's first file (with or without people), else the
    smallest frame of a pose (COCO results leave out the images without anyone)."""
    intrinsics: np.ndarray | None = None
    """f32[N, 3, 3], when the file gives a camera per pose."""
    frame_ids: list[Any] | None = None
    """Every frame in sequence order, those without a pose too (OpenPose files); None: the sorted image_ids."""
    frames_note: str | None = None
    """Set where the image ids gave no frame numbers and the frames were numbered by sequence order."""
    clipped_scores: int = 0
    """Scores above 1 clipped to 1 (`jaxpose.formats.confidences`)."""


def read_detections(path: Path) -> DetectionFile:
    """The poses of `path`, by its kind (`_read_by_kind`), their scores by the one rule of
    `jaxpose.formats.confidences` (a negative one refused, those above 1 clipped and counted)."""
    detections = _read_by_kind(path)
    if detections.scores is None:
        return detections
    with np.errstate(invalid="ignore"):  # NaN scores stay: the lifter reports them as missing
        scores, clipped = confidences.normalise_scores(detections.scores, lambda index: (path, f"pose {index[0]} joint {index[1]}"))
    return dataclasses.replace(detections, scores=scores, clipped_scores=clipped)


def sequence_order(image_id: Any) -> tuple[bool, Any]:
    """The sort key of image ids in sequence order: numbers first, numerically, then names as they sort."""
    return isinstance(image_id, str), image_id


def frame_numbers(image_ids: list[Any], where: Path) -> tuple[np.ndarray, str | None]:
    """int64[N] the frame number of each image id (`image_frame_number`), and None; or, where
    an id has none or two ids share one, their ranks in `sequence_order` and a note saying so."""
    numbers: dict[Any, int | None] = {}
    for image_id in dict.fromkeys(image_ids):
        try:
            numbers[image_id] = image_frame_number(image_id) if isinstance(image_id, int | str) else None
        except DataFormatError:
            numbers[image_id] = None
    problem = next((i for i, n in numbers.items() if n is None), None)
    if problem is None and len(set(numbers.values())) == len(numbers):
        return np.array([numbers[i] for i in image_ids], np.int64), None
    ranked = {image_id: rank for rank, image_id in enumerate(sorted(numbers, key=sequence_order))}
    reason = f"image id {problem!r} has no digits" if problem is not None else "two image ids share a frame number"
    note = f"{where}: {reason}, so the frames are numbered 0, 1, ... in the image ids' order"
    return np.array([ranked[i] for i in image_ids], np.int64), note


def _read_by_kind(path: Path) -> DetectionFile:
    """Dispatch on the path: folder -> OpenPose, .npz, .json (COCO results list or one OpenPose frame)."""
    if not path.exists():
        raise FileNotFoundError(f"input {path} does not exist")
    if path.is_dir() or path.name.endswith(OPENPOSE_SUFFIX):
        return _read_openpose(path)
    if path.suffix == ".npz":
        return _read_npz(path)
    if path.suffix == ".json":
        return _read_openpose(path) if keypoint_files.is_openpose_frame_file(path) else _read_coco(path)
    raise ValueError(f"input {path}: expected a COCO results .json, an OpenPose folder or a .npz")


def _from_rows(kind: Literal["openpose", "coco"], rows: np.ndarray, image_ids: list[Any], where: Path, **frames) -> DetectionFile:
    """rows f32[N, J, 3] of [x, y, score]; `frames` the DetectionFile's frame fields."""
    if not len(rows):
        raise ValueError(f"{where}: no poses to lift")
    return DetectionFile(kind, where, rows[..., :2], rows[..., 2], image_ids, **frames)


def _frame_fields(image_ids: list[Any], where: Path) -> dict[str, Any]:
    """The DetectionFile's frame fields for a file whose image ids tell the frames."""
    frames, note = frame_numbers(image_ids, where)
    return {"frames": frames, "first_frame": int(frames.min()) if len(frames) else 0, "frames_note": note}


def _read_coco(path: Path) -> DetectionFile:
    """COCO keypoint results: one pose per entry, in file order, the image ids as written."""
    image_ids, rows = coco_results.load_coco_entries(path)
    return _from_rows("coco", rows, image_ids, path, **_frame_fields(image_ids, path))


def _read_openpose(path: Path) -> DetectionFile:
    """OpenPose JSON, a folder of per-frame files (in frame-number order) or one such file: a row per person."""
    files = keypoint_files.frame_files(path)
    detections = keypoint_files.read_openpose_frames(files, str(path))
    frame_ids = [frame_stem(os.path.basename(file)) for _, file in files]
    present = np.arange(detections.keypoints.shape[1]) < detections.people[:, None]  # [F, P]
    rows = np.concatenate([detections.keypoints, detections.scores[..., None]], -1)[present]
    image_ids = np.repeat(np.array(frame_ids, object), detections.people).tolist()
    frames = np.repeat(detections.frames, detections.people)
    return _from_rows("openpose", rows, image_ids, path, frame_ids=frame_ids, frames=frames,
                      first_frame=int(detections.frames[0]))  # fmt: skip


def _read_npz(path: Path) -> DetectionFile:
    """keypoints [N, J, 2], optional confidence [N, J], image_id [N], K [N, 3, 3]."""
    with np.load(path, allow_pickle=False) as data:
        if "keypoints" not in data:
            raise ValueError(f"{path}: no 'keypoints' array (found {sorted(data.files)})")
        keypoints = np.asarray(data["keypoints"], np.float32)
        if keypoints.ndim != 3 or keypoints.shape[-1] != 2:
            raise ValueError(f"{path}: 'keypoints' must be [N, J, 2] pixels, got shape {keypoints.shape}")
        count = len(keypoints)
        scores = np.asarray(data["confidence"], np.float32) if "confidence" in data else None
        image_ids = data["image_id"].tolist() if "image_id" in data else list(range(count))
        intrinsics = np.asarray(data["K"], np.float32) if "K" in data else None
    if len(image_ids) != count:
        raise ValueError(f"{path}: 'image_id' has {len(image_ids)} entries for {count} poses")
    if intrinsics is not None and intrinsics.shape != (count, 3, 3):
        raise ValueError(f"{path}: 'K' must be [N, 3, 3] = {(count, 3, 3)}, got {intrinsics.shape}")
    return DetectionFile("npz", path, keypoints, scores, image_ids, **_frame_fields(image_ids, path), intrinsics=intrinsics)
