"""A rig project's recordings as found and read: the recording folders and calibration files found
(`find_project`), each camera's detections read (OpenPose JSON frames, COCO results or a
``detections.npz``), the keypoint layout decided, the detections brought onto the lifting skeleton, and
a recording's ground truth on its instants (the folder is described in `jaxpose.rig.project`).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import pathlib
from collections.abc import Mapping, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from jaxpose.data import ground_truth
from jaxpose.formats import detections_npz
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.keypoint_files import CameraDetections, read_camera_detections
from jaxpose.formats.calibration_files import find_calibration
from jaxpose.formats.rig_folder import (
    DETECTIONS_NPZ,
    GROUND_TRUTH_NPZ,
    folder_camera,
    read_ground_truth,
)
from jaxpose.layouts import (
    LAYOUTS,
    check_body25_layout,
    infer_layout,
    layout_joint_names,
    to_lifting_skeleton,
)
from jaxpose.skeleton import DETECTOR_LAYOUTS, Skeleton

log = logging.getLogger(__name__)

MAX_PEOPLE = 4  # detections per camera and frame kept for the choice of person

Views = dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]
"""Camera -> (frames int[F], keypoints f32[F, P, J, 2], confidence f32[F, P, J]): up to P people per frame."""


@dataclasses.dataclass(frozen=True)
class Recording:
    """One recording as found (`find_project`): its folder, where each camera's detections are, its own calibration."""

    name: str
    folder: pathlib.Path
    cameras: tuple[str, ...]
    """Its cameras' names (detection folders, COCO files or the detections.npz's camera_names)."""
    sources: dict[str, pathlib.Path]
    """Camera -> its JSON folder or COCO file; {DETECTIONS_NPZ: path} for a detections.npz."""
    calibration: pathlib.Path | None
    """Its own calibration file (it overrides the project's), None without one."""


@dataclasses.dataclass(frozen=True)
class FoundProject:
    """A project folder as found, nothing read but a detections.npz's camera names: its recordings and the
    calibration files that give their rigs."""

    root: pathlib.Path
    recordings: tuple[Recording, ...]
    calibration: pathlib.Path | None
    """The rig of every recording without its own: --data.calibration, else the file found in the project
    folder; None without either."""

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(recording.name for recording in self.recordings)

    @property
    def calibrated(self) -> bool:
        """Whether any calibration file gives a rig (else the rig is recovered from the recordings)."""
        return self.calibration is not None or any(recording.calibration is not None for recording in self.recordings)


def find_project(root: pathlib.Path, names: Sequence[str] = (), calibration: pathlib.Path | None = None) -> FoundProject:
    """The project's recordings (all, or those `names`: --data.recordings) and calibration files
    (`calibration`: --data.calibration, else the one in the project folder)."""
    recordings = tuple(find_recording(folder) for folder in recording_folders(root, names))
    return FoundProject(root, recordings, calibration if calibration is not None else find_calibration(root))


@dataclasses.dataclass(frozen=True)
class RecordingDetections:
    """One recording's detections as read (`read_detections`), let go after alignment."""

    recording: Recording
    cameras: dict[str, CameraDetections]
    layout: str
    """The keypoint layout they are in (`jaxpose.layouts`)."""
    known_cameras: dict[str, dict]
    """Camera -> what a detections.npz gives of it: image_size, K, dist (those present) and model; {} for JSON."""


def printable(path: pathlib.Path | str) -> str:
    """A path as text that any terminal and file can take: bytes that are not UTF-8 as \\xNN escapes."""
    return os.fsencode(path).decode("utf-8", "backslashreplace")


def _utf8_name(path: pathlib.Path, what: str) -> None:
    """Refuse a file or folder name that is not UTF-8: it names a recording or camera in every report."""
    try:
        path.name.encode("utf-8")
    except UnicodeEncodeError:
        raise DataFormatError(printable(path), f"a {what} name in UTF-8 (it names the {what} in the report)", "other bytes") from None


def _is_dir(path: pathlib.Path) -> bool:
    """`path.is_dir()`; a symbolic link that loops (in a circle, or to a folder that holds it) is refused in one line."""
    if path.is_symlink():
        try:
            loops = path.parent.resolve().is_relative_to(path.resolve(strict=True))
        except FileNotFoundError:
            return False  # a link to nothing: not a folder
        except (OSError, RuntimeError):
            loops = True
        if loops:
            raise DataFormatError(printable(path), "a folder or a file", "a symbolic link that loops (to itself or a folder holding it)")
    return path.is_dir()


def recording_folders(root: pathlib.Path, names: Sequence[str] = ()) -> list[pathlib.Path]:
    """The project's recording folders (sub-folders holding detections), sorted by name."""
    if not root.is_dir():
        raise DataFormatError(root, "a rig project folder (one sub-folder per recording)", "no such folder")
    folders = []
    for folder in sorted(root.iterdir()):
        if folder.name.startswith(".") or not _is_dir(folder) or not _camera_sources(folder, probe=True):
            continue
        _utf8_name(folder, "recording")
        folders.append(folder)
    if names:
        by_name = {folder.name: folder for folder in folders}
        unknown = [name for name in names if name not in by_name]
        if unknown:
            raise DataFormatError(root, f"recordings {list(names)} (--data.recordings)", f"recordings {sorted(by_name)}; {unknown} missing")
        folders = [by_name[name] for name in names]
    if not folders:
        raise DataFormatError(
            root,
            f"recording folders holding {DETECTIONS_NPZ}, camera folders of OpenPose JSON frames or COCO results per camera",
            f"no such sub-folder (found {sorted(printable(p.name) for p in root.iterdir())[:20]})",
        )
    return folders


def _camera_sources(folder: pathlib.Path, calibration: pathlib.Path | None = None, probe: bool = False) -> dict[str, pathlib.Path]:
    """Camera name -> its detections (a JSON folder or a COCO results file); {DETECTIONS_NPZ: path} for the
    npz.  `calibration`: the folder's calibration file, which is no camera's detections."""
    if (folder / DETECTIONS_NPZ).is_file():
        return {DETECTIONS_NPZ: folder / DETECTIONS_NPZ}
    folders = {
        folder_camera(entry.name): entry
        for entry in sorted(folder.iterdir())
        if not entry.name.startswith(".") and _is_dir(entry) and next(entry.glob("*.json"), None) is not None
    }
    files = {
        entry.stem: entry for entry in sorted(folder.glob("*.json")) if not entry.name.startswith(".") and entry != calibration
    }
    if probe:
        return folders or files
    if folders and files:
        raise DataFormatError(
            folder,
            "one kind of detections per recording: camera folders of OpenPose JSON frames, or COCO results files",
            f"both folders {sorted(folders)} and JSON files {sorted(files)}",
        )
    return folders or files


def find_recording(folder: pathlib.Path) -> Recording:
    """A recording folder's cameras, where their detections are and its own calibration file (nothing read
    but a detections.npz's camera names)."""
    calibration = find_calibration(folder)
    sources = _camera_sources(folder, calibration)
    if DETECTIONS_NPZ in sources:
        cameras = detections_npz.read_camera_names(sources[DETECTIONS_NPZ])
    else:
        for path in sources.values():
            _utf8_name(path, "camera")
        cameras = tuple(sources)
    if len(cameras) < 2:
        raise DataFormatError(
            folder, "detections of at least 2 cameras (multi-view geometry needs two views)", f"cameras {sorted(cameras)}"
        )
    return Recording(name=folder.name, folder=folder, cameras=cameras, sources=sources, calibration=calibration)


def _npz_cameras(detections: detections_npz.MultiViewDetections) -> dict[str, CameraDetections]:
    """A detections.npz as per-camera detections (one person per frame, or its person axis)."""
    keypoints, confidence = detections.keypoints, detections.confidence
    if keypoints.ndim == 4:
        keypoints, confidence = keypoints[:, :, None], confidence[:, :, None]
    found = (confidence > 0).any(-1)  # [N, C, P]
    slots = np.arange(1, found.shape[-1] + 1)
    return {
        name: CameraDetections(
            frames=detections.frames,
            keypoints=keypoints[:, c],
            scores=confidence[:, c],
            people=np.max(np.where(found[:, c], slots, 0), axis=-1, initial=0).astype(np.int32),
            source=f"{detections.source} (camera {name})",
        )
        for c, name in enumerate(detections.camera_names)
    }


def _layout(
    skeleton: str, recording: str, cameras: Mapping[str, CameraDetections], npz: detections_npz.MultiViewDetections | None
) -> str:
    """The keypoint layout of one recording's detections (`skeleton`: see `RigProjectConfig.skeleton`)."""
    if skeleton != "auto":
        if skeleton not in LAYOUTS:
            raise ValueError(f"--data.skeleton {skeleton!r}: expected auto or one of {list(LAYOUTS)}")
        layout = skeleton
    elif npz is not None and npz.skeleton is not None:
        layout = npz.skeleton
    else:
        counts = {name: detections.values_per_person for name, detections in cameras.items() if detections.keypoints.shape[1]}
        if len(set(counts.values())) > 1:
            raise DataFormatError(f"recording {recording}", "the same keypoint count in every camera", f"values per person {counts}")
        if not counts:
            raise DataFormatError(f"recording {recording}", "detections in at least one camera", "nobody detected")
        camera, count = next(iter(counts.items()))
        layout = infer_layout(count, f"recording {recording}, camera {camera} ({cameras[camera].source})")
    expected = len(layout_joint_names(layout))
    for name, detections in cameras.items():
        if detections.keypoints.shape[1] and detections.keypoints.shape[2] != expected:
            raise DataFormatError(
                detections.source, f"{expected} keypoints per person (layout {layout})", f"{detections.keypoints.shape[2]}"
            )
    return layout


def read_detections(recording: Recording, skeleton: str, progress: bool, parsed: pathlib.Path) -> RecordingDetections:
    """The recording's detections, per camera, their layout (`skeleton`: see `RigProjectConfig.skeleton`)
    and, from a detections.npz, what it gives of each camera.  JSON detections are parsed once and cached
    in the folder `parsed` (the project's cache), one file per camera."""
    npz, known = None, {}
    if DETECTIONS_NPZ in recording.sources:
        npz = detections_npz.read(recording.sources[DETECTIONS_NPZ], people=True)
        cameras = _npz_cameras(npz)
        given = {key: getattr(npz, key) for key in ("image_size", "K", "dist") if getattr(npz, key) is not None}
        known = {
            camera: {key: array[index] for key, array in given.items()} | {"model": npz.distortion_model}
            for index, camera in enumerate(npz.camera_names)
        }
    else:
        cameras = {name: read_camera_detections(path, progress, parsed / f"{path.name}.npz") for name, path in recording.sources.items()}
    return RecordingDetections(recording, cameras, _layout(skeleton, recording.name, cameras, npz), known)


def lifting_views(read: RecordingDetections, min_confidence: float) -> Views:
    """The recording's `Views` in the lifting skeleton, scores below `min_confidence` made 0, at most `MAX_PEOPLE` detections per frame
    (the most confident: a crowd only costs memory; the frames where more were left out are logged in one line per camera), and at
    least one (a camera that never saw anybody keeps an empty slot).  A BODY_25 / BODY_25B layout is checked on every camera's
    poses together (`check_body25_layout`): one camera's few people (a false detection, a person with arms down) can mislead it."""
    views = {}
    joints = len(layout_joint_names(read.layout))
    pooled = []
    for name, detections in read.cameras.items():
        keypoints, scores = detections.keypoints, detections.scores
        if keypoints.shape[1] == 0:
            keypoints, scores = np.zeros((len(keypoints), 1, joints, 2), np.float32), np.zeros((len(keypoints), 1, joints), np.float32)
        if keypoints.shape[1] > MAX_PEOPLE:
            crowded = int(((scores > 0).any(-1).sum(-1) > MAX_PEOPLE).sum())
            log.warning("recording %s, camera %s: %d frames with more than %d people detected: the %d most confident of each kept",
                        read.recording.name, name, crowded, MAX_PEOPLE, MAX_PEOPLE)  # fmt: skip
            order = np.argsort(-np.nan_to_num(scores).sum(-1), axis=1, kind="stable")[:, :MAX_PEOPLE]
            keypoints = np.take_along_axis(keypoints, order[..., None, None], axis=1)
            scores = np.take_along_axis(scores, order[..., None], axis=1)
        pooled.append((keypoints.reshape(-1, *keypoints.shape[2:]), scores.reshape(-1, scores.shape[-1])))
        views[name] = (detections.frames, keypoints, scores)
    if pooled:
        where = printable(read.recording.folder) + f" (cameras {', '.join(views)})"
        check_body25_layout(read.layout, np.concatenate([k for k, _ in pooled]), np.concatenate([c for _, c in pooled]), where, "--data.skeleton")
    for name, (frames, keypoints, scores) in views.items():
        keypoints, confidence = to_lifting_skeleton(read.layout, keypoints, scores)
        confidence = np.where(confidence >= min_confidence, confidence, 0.0).astype(np.float32)
        views[name] = (frames, keypoints, confidence)
    return views


def one_person(keypoints: np.ndarray, confidence: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[..., P, J, 2], [..., P, J] -> the only detection where there is exactly one, else confidence 0:
    what frame offsets and a recovered rig are estimated from (no choice of person needed)."""
    detected = (confidence > 0).any(-1)  # [..., P]
    person = np.argmax(detected, axis=-1)[..., None]
    chosen = np.take_along_axis(keypoints, person[..., None, None], axis=-3)[..., 0, :, :]
    chosen_confidence = np.take_along_axis(confidence, person[..., None], axis=-2)[..., 0, :]
    return chosen, np.where((detected.sum(-1) == 1)[..., None], chosen_confidence, 0.0).astype(np.float32)


def ground_truth_on_instants(folder: pathlib.Path, skeleton: Skeleton, layout: str, instants: np.ndarray) -> tuple[np.ndarray | None, int]:
    """The recording's ground truth on its instants: (f32[N, P, J, 3] world mm of its P people, NaN where
    unknown, or None; instants with it)."""
    path = folder / GROUND_TRUTH_NPZ
    if not path.is_file():
        return None, 0
    truth = read_ground_truth(path)
    root_from = DETECTOR_LAYOUTS[layout].root_from if layout in DETECTOR_LAYOUTS else None
    people = truth.points.shape[1]
    matched = np.stack([
        ground_truth.on_skeleton(truth.points[:, person], truth.joint_names, skeleton, root_from, f"{path}, array 'joint_names'")
        for person in range(people)
    ], 1)  # fmt: skip
    target = np.full((len(instants), people, skeleton.num_joints, 3), np.nan, np.float32)
    _, rows, gt_rows = np.intersect1d(instants, truth.frames, return_indices=True)
    target[rows] = matched[gt_rows]
    return target, len(rows)


TRUTH_MATCH_MM = 300.0
"""The largest median joint distance (mm) of a prepared person from a ground-truth person for it to be that one."""


def truth_of_people(target: np.ndarray, instant: np.ndarray, person: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Each prepared row's ground truth: target f32[N, P, J, 3] (`ground_truth_on_instants`), the rows' instant
    int[R] and person int[R] and their triangulated joints f32[R, J, 3] (NaN where unseen) -> f32[R, J, 3].
    With one ground-truth person and one prepared person, that person's; else each prepared person is given the
    ground-truth person nearest to it (the median joint distance over the instants both have, one to one,
    `scipy.optimize.linear_sum_assignment`) within `TRUTH_MATCH_MM`, and NaN where none is."""
    if target.shape[1] == 1 and (person == person[0]).all():
        return target[instant, 0]
    ids = np.unique(person)
    cost = np.full((len(ids), target.shape[1]), np.inf)
    for row, k in enumerate(ids):
        rows = person == k
        distance = np.linalg.norm(target[instant[rows]] - points[rows, None], axis=-1)  # [r, P, J]
        finite = np.isfinite(distance)
        with np.errstate(invalid="ignore"):
            median = np.array([np.median(distance[:, p][finite[:, p]]) if finite[:, p].any() else np.inf for p in range(target.shape[1])])
        cost[row] = median
    out = np.full((len(person), *target.shape[2:]), np.nan, np.float32)
    rows, columns = linear_sum_assignment(np.where(np.isfinite(cost), cost, 1e12))
    for row, column in zip(rows, columns):
        if cost[row, column] <= TRUTH_MATCH_MM:
            mine = person == ids[row]
            out[mine] = target[instant[mine], column]
    return out
