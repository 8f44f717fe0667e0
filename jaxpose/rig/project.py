"""A user's own rig: multi-camera recordings of a person, in the formats users already have, as data sets.

A project folder::

    PROJECT/
      <calibration>              optional: the rig of every recording (see below)
      <recording>/               one folder per recording (a trial, a session) of that rig
        detections.npz           jaxpose's multi-view arrays (`jaxpose.formats.detections_npz`: keypoints
                                 [N, C, J, 2] px, camera_names, optional confidence, frames [N],
                                 image_size, skeleton, K/dist/distortion_model), or
        <camera>/ or <camera>_json/   one folder per camera of OpenPose-style JSON frames, or
        <camera>.json            one COCO keypoint-results file per camera (image_id = frame number)
        <calibration>            optional: this recording's own rig, overriding the project's
        ground_truth.npz         optional, evaluation only: points3d [N, J, 3] world mm (the
                                 calibration's world frame), frames [N], joint_names [J]

Calibrations (`jaxpose.formats.rig_calibration`): a jaxpose camera file, an Anipose / Pose2Sim /
FreeMoCap TOML, or EasyMocap's intri.yml + extri.yml, found in a folder by their content.  Cameras
are matched to the detection folders by name (a folder's name without `_json`), ignoring case,
separators and leading zeros where that matches them one to one ("cam_01" is folder "cam01_json").  Without any
calibration the rig is recovered from the recordings (`jaxpose.calibrate`).

What loading does to each recording, in order:
1. reads every camera's detections (parsed once, then cached: `jaxpose.formats.keypoint_files`);
2. converts them from the detector's layout to its lifting skeleton (the detector's own joints,
   root first: `jaxpose.layouts.to_lifting_skeleton`); scores below `min_confidence` are
   treated as missing;
3. aligns the cameras in time: camera c's frame f shows instant f + offset[c]; offsets given, or
   estimated (`jaxpose.rig.sync`); instants seen by no camera are absent, a camera without a
   frame at an instant has confidence 0 there;
4. undistorts the keypoints with the calibration (the data sets' rigs are then pinhole);
5. keeps one person per instant, the one the views agree on (`jaxpose.rig.people`);
6. attaches the ground truth where there is one, over the joints it shares with the lifting
   skeleton by name (the derived root from the hips where the ground truth has both).
"""

from __future__ import annotations

import dataclasses
import logging
import pathlib
import re
from collections.abc import Mapping, Sequence
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.camera import Cameras, projection_matrices, undistort_points
from jaxpose.formats.rig_calibration import CalibrationUnit, RigCalibration, find_calibration, read_rig_calibration
from jaxpose.data import ground_truth
from jaxpose.data.dataset import MultiViewDataset, concatenate
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats import detections_npz
from jaxpose.formats.keypoint_files import CameraDetections, read_camera_detections
from jaxpose.formats.rig_folder import DETECTIONS_NPZ, GROUND_TRUTH_NPZ, folder_camera, read_ground_truth
from jaxpose.rig.people import DEFAULT_THRESHOLD_PX, choose_person
from jaxpose.rig.sync import SyncEstimate, estimate_offsets
from jaxpose.layouts import LAYOUTS, infer_layout, layout_joint_names, lifting_skeleton, to_lifting_skeleton
from jaxpose.skeleton import DETECTOR_LAYOUTS, Skeleton

log = logging.getLogger(__name__)

MAX_PEOPLE = 4  # detections per camera and frame kept for the choice of person
MIN_ALIGNMENT_POINTS = 50  # ground-truth joints needed to align it with a recovered rig


@dataclasses.dataclass(frozen=True)
class RigProjectConfig:
    """A rig project folder and how its recordings are read (see `jaxpose.rig.project`)."""

    root: pathlib.Path = pathlib.Path("runs/rig_example/project")
    """The project folder: one sub-folder per recording, and optionally a calibration file."""
    calibration: pathlib.Path | None = None
    """A calibration for every recording (a recording's own calibration file still overrides it);
    None = the calibration file found in the project folder, if any; none anywhere = the rig is
    recovered from the recordings."""
    calibration_unit: CalibrationUnit = "auto"
    """Length unit of a TOML or EasyMocap calibration: Pose2Sim and EasyMocap write metres, Anipose the
    board's unit (usually mm), FreeMoCap mm.  auto: metres if the cameras lie within 100 units of each
    other, else mm (cm must be given)."""
    recordings: tuple[str, ...] = ()
    """Recordings (sub-folder names) to use; empty = all of them."""
    skeleton: str = "auto"
    """Keypoint layout of the detections: body25, body25b, coco17, coco18, halpe26 or a jaxpose
    skeleton name; auto = from the number of keypoints (75 values per person is ambiguous: BODY_25 or
    BODY_25B), or the `skeleton` array of a detections.npz."""
    min_confidence: float = 0.1
    """Keypoints scored below this are treated as not detected."""
    frame_offsets: tuple[str, ...] = ()
    """Cameras not started together: CAMERA=N (every recording) or RECORDING/CAMERA=N, meaning that
    camera's frame f shows the instant of the other cameras' frame f + N."""
    sync: Literal["given", "auto"] = "given"
    """given: --data.frame-offsets (default 0); auto: estimate every camera's integer offset per
    recording from the detections (epipolar geometry), reported and used (given offsets are ignored)."""
    max_sync_offset: int = 10
    """auto sync: the largest offset tried, in frames."""
    person_threshold_px: float = DEFAULT_THRESHOLD_PX
    """A view's detection belongs to the chosen person when it lies within this median distance (px)
    of that person's projection; views without one get confidence 0 at that instant."""
    recovery_frames: int = 600
    """Without a calibration: the instants (spread over all recordings) the rig is recovered from
    (`jaxpose.calibrate`'s max_frames: 600 take ~25 s on 2 cores)."""
    image_size: tuple[int, int] | None = None
    """Width and height of the images (px), needed only to recover the rig of JSON detections without
    any calibration (a detections.npz carries its own)."""
    validation_recordings: tuple[str, ...] = ()
    """Recordings held out for validation; empty = the last --data.validation-fraction of every recording."""
    validation_fraction: float = 0.2
    """With no --data.validation-recordings: the final block of each recording (a fraction of its
    instants) validates; the rest trains."""
    train_stride: int = 1
    """Keep every n-th instant of the training part."""
    validation_stride: int = 1
    """Keep every n-th instant of the validation part."""

    def __post_init__(self):
        if not 0.0 < self.validation_fraction < 1.0:
            raise ValueError(f"--data.validation-fraction must lie in (0, 1), got {self.validation_fraction}")
        if self.train_stride < 1 or self.validation_stride < 1 or self.max_sync_offset < 0:
            raise ValueError("--data.train-stride and --data.validation-stride must be >= 1, --data.max-sync-offset >= 0")


@dataclasses.dataclass(frozen=True)
class RecordingSummary:
    """What loading did to one recording, for the report."""

    name: str
    cameras: tuple[str, ...]
    instants: int
    calibration: str
    offsets: dict[str, int]
    offsets_estimated: bool
    sync_reliable: bool | None
    instants_with_choice: int
    views_without_match: int
    ground_truth_instants: int


@dataclasses.dataclass(frozen=True)
class RigProject:
    """A loaded project: the training and validation parts and how they were made."""

    train: MultiViewDataset
    validation: MultiViewDataset
    camera_names: tuple[str, ...]
    layout: str
    recordings: tuple[RecordingSummary, ...]
    ground_truth_joints: tuple[str, ...]
    """The lifting skeleton's joints that the ground truth has (empty without ground truth)."""
    recovered_calibration: object | None = None
    """The `jaxpose.calibration.Calibration` recovered from the recordings, when there was no calibration."""


@dataclasses.dataclass
class _Recording:
    """One recording while it is being loaded."""

    name: str
    folder: pathlib.Path
    cameras: dict[str, CameraDetections]
    layout: str
    npz: detections_npz.MultiViewDetections | None = None
    calibration: RigCalibration | None = None
    offsets: dict[str, int] = dataclasses.field(default_factory=dict)
    sync: SyncEstimate | None = None


def recording_folders(root: pathlib.Path, names: Sequence[str] = ()) -> list[pathlib.Path]:
    """The project's recording folders (sub-folders holding detections), sorted by name."""
    if not root.is_dir():
        raise DataFormatError(root, "a rig project folder (one sub-folder per recording)", "no such folder")
    folders = [
        folder for folder in sorted(root.iterdir())
        if folder.is_dir() and not folder.name.startswith(".") and _camera_sources(folder, probe=True)
    ]  # fmt: skip
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
            f"no such sub-folder (found {sorted(p.name for p in root.iterdir())[:20]})",
        )
    return folders


def _camera_sources(folder: pathlib.Path, probe: bool = False) -> dict[str, pathlib.Path]:
    """Camera name -> its detections (a JSON folder or a COCO results file); {DETECTIONS_NPZ: path} for the npz."""
    if (folder / DETECTIONS_NPZ).is_file():
        return {DETECTIONS_NPZ: folder / DETECTIONS_NPZ}
    folders = {
        folder_camera(entry.name): entry
        for entry in sorted(folder.iterdir())
        if entry.is_dir() and not entry.name.startswith(".") and next(entry.glob("*.json"), None) is not None
    }
    calibration = None if probe else find_calibration(folder)  # a recording's own camera file is no camera
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


def _npz_cameras(detections: detections_npz.MultiViewDetections) -> dict[str, CameraDetections]:
    """A detections.npz as per-camera detections (one person per frame)."""
    return {
        name: CameraDetections(
            frames=detections.frames,
            keypoints=detections.keypoints[:, c, None],
            scores=detections.confidence[:, c, None],
            people=(detections.confidence[:, c] > 0).any(-1).astype(np.int32),
            source=f"{detections.source} (camera {name})",
        )
        for c, name in enumerate(detections.camera_names)
    }


def _layout(
    config: RigProjectConfig, recording: str, cameras: Mapping[str, CameraDetections], npz: detections_npz.MultiViewDetections | None
) -> str:
    """The keypoint layout of one recording's detections (see `RigProjectConfig.skeleton`)."""
    if config.skeleton != "auto":
        if config.skeleton not in LAYOUTS:
            raise ValueError(f"--data.skeleton {config.skeleton!r}: expected auto or one of {list(LAYOUTS)}")
        layout = config.skeleton
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


def _read_recording(config: RigProjectConfig, folder: pathlib.Path, progress: bool) -> _Recording:
    sources = _camera_sources(folder)
    npz = None
    if DETECTIONS_NPZ in sources:
        npz = detections_npz.read(sources[DETECTIONS_NPZ])
        cameras = _npz_cameras(npz)
    else:
        cameras = {name: read_camera_detections(path, progress=progress) for name, path in sources.items()}
    if len(cameras) < 2:
        raise DataFormatError(
            folder, "detections of at least 2 cameras (multi-view geometry needs two views)", f"cameras {sorted(cameras)}"
        )
    layout = _layout(config, folder.name, cameras, npz)
    return _Recording(name=folder.name, folder=folder, cameras=cameras, layout=layout, npz=npz)


def parse_frame_offsets(values: Sequence[str], recordings: Sequence[_Recording]) -> dict[tuple[str, str], int]:
    """--data.frame-offsets as {(recording, camera): offset}; CAMERA=N applies to every recording that has the camera."""
    offsets = {}
    for value in values:
        match = re.fullmatch(r"(?:(?P<recording>[^/=]+)/)?(?P<camera>[^/=]+)=(?P<offset>[+-]?\d+)", value.strip())
        if match is None:
            raise ValueError(f"--data.frame-offsets {value!r}: expected CAMERA=N or RECORDING/CAMERA=N (N an integer)")
        targets = [r for r in recordings if match["recording"] in (None, r.name)]
        if not targets:
            raise ValueError(f"--data.frame-offsets {value!r}: no recording {match['recording']!r} (have {[r.name for r in recordings]})")
        having = [r for r in targets if match["camera"] in r.cameras]
        if not having:
            cameras = sorted(set().union(*(r.cameras for r in targets)))
            raise ValueError(f"--data.frame-offsets {value!r}: no camera {match['camera']!r} in {[r.name for r in targets]} (cameras {cameras})")
        for recording in having:
            offsets[recording.name, match["camera"]] = int(match["offset"])
    return offsets


def _camera_key(name: str) -> str:
    """A camera name without case, separators and leading zeros: "cam_01", "Cam1", "cam01" -> "cam1"."""
    return re.sub(r"\d+", lambda digits: str(int(digits.group())), re.sub(r"[^0-9a-z]", "", name.lower()))


def _named_as_detections(calibration: RigCalibration, detection_names: set[str]) -> RigCalibration:
    """The calibration with its cameras named as the detection folders where the names differ only in
    case, separators or leading zeros and match one to one (Pose2Sim's calibrations call the cameras of
    its `cam01_json` folders "cam_01")."""
    if detection_names <= set(calibration.camera_names):
        return calibration
    by_key = {_camera_key(name): name for name in detection_names}
    keys = [_camera_key(name) for name in calibration.camera_names]
    if len(set(keys)) != len(keys) or len(by_key) != len(detection_names) or not set(by_key) <= set(keys):
        return calibration  # no one-to-one match: the exact names decide, and their mismatch is reported
    renamed = tuple(by_key.get(key, name) for key, name in zip(keys, calibration.camera_names))
    log.info("%s: cameras %s matched to the detection folders %s", calibration.source, calibration.camera_names, renamed)
    return dataclasses.replace(calibration, camera_names=renamed)


def _calibrations(config: RigProjectConfig, recordings: Sequence[_Recording]) -> RigCalibration | None:
    """Attach each recording's calibration; returns the project-wide one (None: none anywhere)."""
    project_file = config.calibration or find_calibration(config.root)
    project = None if project_file is None else read_rig_calibration(project_file, config.calibration_unit)
    if project is not None:
        project = _named_as_detections(project, set().union(*(recording.cameras for recording in recordings)))
    for recording in recordings:
        own = find_calibration(recording.folder)
        if own is None:
            recording.calibration = project
        else:
            recording.calibration = _named_as_detections(read_rig_calibration(own, config.calibration_unit), set(recording.cameras))
    if project is not None:
        used = set().union(*(recording.cameras for recording in recordings if recording.calibration is project))
        unused = [name for name in project.camera_names if name not in used]
        if unused and used:
            raise DataFormatError(
                project.source,
                f"a detection folder for each of its cameras {list(project.camera_names)}",
                f"cameras {unused} have no detections in any recording (detection folders: {sorted(used)})",
            )
    missing = [recording.name for recording in recordings if recording.calibration is None]
    if missing and len(missing) < len(recordings):
        raise DataFormatError(config.root, "a calibration for every recording, or for none", f"none for recordings {missing}")
    return project


def _lifting_views(recording: _Recording, config: RigProjectConfig) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Camera -> (frames [F], keypoints [F, P, J, 2], confidence [F, P, J]) in the lifting skeleton,
    at most `MAX_PEOPLE` detections per frame (the most confident: a crowd only costs memory), and at
    least one (a camera that never saw anybody keeps an empty slot)."""
    views = {}
    joints = len(layout_joint_names(recording.layout))
    for name, detections in recording.cameras.items():
        keypoints, scores = detections.keypoints, detections.scores
        if keypoints.shape[1] == 0:
            keypoints, scores = np.zeros((len(keypoints), 1, joints, 2), np.float32), np.zeros((len(keypoints), 1, joints), np.float32)
        if keypoints.shape[1] > MAX_PEOPLE:
            order = np.argsort(-np.nan_to_num(scores).sum(-1), axis=1, kind="stable")[:, :MAX_PEOPLE]
            keypoints = np.take_along_axis(keypoints, order[..., None, None], axis=1)
            scores = np.take_along_axis(scores, order[..., None], axis=1)
        keypoints, confidence = to_lifting_skeleton(recording.layout, keypoints, scores)
        confidence = np.where(confidence >= config.min_confidence, confidence, 0.0).astype(np.float32)
        views[name] = (detections.frames, keypoints, confidence)
    return views


def _one_person(keypoints: np.ndarray, confidence: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[..., P, J, 2], [..., P, J] -> the only detection where there is exactly one, else confidence 0:
    what frame offsets and a recovered rig are estimated from (no choice of person needed)."""
    detected = (confidence > 0).any(-1)  # [..., P]
    person = np.argmax(detected, axis=-1)[..., None]
    chosen = np.take_along_axis(keypoints, person[..., None, None], axis=-3)[..., 0, :, :]
    chosen_confidence = np.take_along_axis(confidence, person[..., None], axis=-2)[..., 0, :]
    return chosen, np.where((detected.sum(-1) == 1)[..., None], chosen_confidence, 0.0).astype(np.float32)


def _in_view_order(calibration: RigCalibration, camera_order: Sequence[str]) -> RigCalibration:
    """A recording's rig in the data set's view order.  A camera of the project that this recording
    lacks (and so its own calibration may lack) gets a copy of the rig's first camera: the slot is
    never used, its view has confidence 0 throughout."""
    present = [camera for camera in camera_order if camera in calibration.camera_names]
    rig = calibration.select(present, "cameras of the project")
    if len(present) == len(camera_order):
        return rig
    index = np.array([present.index(camera) if camera in present else 0 for camera in camera_order])
    return dataclasses.replace(
        rig,
        camera_names=tuple(camera_order),
        cameras=rig.cameras[index],
        image_size=None if rig.image_size is None else rig.image_size[index],
    )


def _undistorted(calibration: RigCalibration | None, camera: str, keypoints: np.ndarray) -> np.ndarray:
    if calibration is None or calibration.cameras.dist is None:
        return keypoints
    index = calibration.camera_names.index(camera)
    cameras = jax.tree.map(lambda field: jnp.asarray(field[index], jnp.float32), calibration.cameras)
    flat = keypoints.reshape(-1, 2)
    return np.asarray(undistort_points(cameras, jnp.asarray(flat))).reshape(keypoints.shape)


def _estimate_sync(recording: _Recording, views: Mapping, camera_order: Sequence[str], config: RigProjectConfig) -> SyncEstimate:
    """`jaxpose.rig.sync.estimate_offsets` on the frames where each camera sees one person."""
    frames, keypoints, confidence = [], [], []
    for camera in camera_order:
        camera_frames, camera_keypoints, camera_confidence = views[camera]
        single_keypoints, single_confidence = _one_person(camera_keypoints, camera_confidence)
        rows = np.flatnonzero((single_confidence > 0).any(-1))
        frames.append(camera_frames[rows])
        keypoints.append(_undistorted(recording.calibration, camera, single_keypoints[rows]))
        confidence.append(single_confidence[rows])
    projections = None
    if recording.calibration is not None:
        rig = recording.calibration.select(camera_order, f"cameras of recording {recording.name}")
        projections = np.asarray(projection_matrices(rig.cameras.without_distortion()), np.float64)
    return estimate_offsets(frames, keypoints, confidence, projections, config.max_sync_offset)


def _align(views: Mapping, camera_order: Sequence[str], offsets: Mapping[str, int]):
    """The cameras on one time axis: (instants [N], keypoints [N, C, P, J, 2], confidence [N, C, P, J])."""
    instants = np.unique(np.concatenate([views[c][0] + offsets.get(c, 0) for c in camera_order if c in views]))
    people = max(views[c][1].shape[1] for c in views)
    J = next(iter(views.values()))[1].shape[2]
    keypoints = np.zeros((len(instants), len(camera_order), people, J, 2), np.float32)
    confidence = np.zeros((len(instants), len(camera_order), people, J), np.float32)
    for index, camera in enumerate(camera_order):
        if camera not in views:
            continue  # a camera this recording lacks: confidence 0 throughout
        frames, camera_keypoints, camera_confidence = views[camera]
        rows = np.searchsorted(instants, frames + offsets.get(camera, 0))
        width = camera_keypoints.shape[1]
        keypoints[rows, index, :width] = camera_keypoints
        confidence[rows, index, :width] = camera_confidence
    return instants, keypoints, confidence


def _ground_truth(folder: pathlib.Path, skeleton: Skeleton, layout: str, instants: np.ndarray) -> tuple[np.ndarray | None, int]:
    """The recording's ground truth on its instants: (f32[N, J, 3] world mm, NaN where unknown, or None; instants with it)."""
    path = folder / GROUND_TRUTH_NPZ
    if not path.is_file():
        return None, 0
    truth = read_ground_truth(path)
    root_from = DETECTOR_LAYOUTS[layout].root_from if layout in DETECTOR_LAYOUTS else None
    matched = ground_truth.on_skeleton(truth.points, truth.joint_names, skeleton, root_from, f"{path}, array 'joint_names'")
    target = np.full((len(instants), skeleton.num_joints, 3), np.nan, np.float32)
    _, rows, gt_rows = np.intersect1d(instants, truth.frames, return_indices=True)
    target[rows] = matched[gt_rows]
    return target, len(rows)


def _recover_rig(config: RigProjectConfig, recordings: Sequence[_Recording], aligned: Mapping, camera_order: Sequence[str], skeleton: Skeleton):
    """`jaxpose.calibrate` on the instants of all recordings, each view's detection where it saw one person."""
    from jaxpose.calibration import CalibrationConfig, RigDetections, calibrate  # the calibrate extra

    keypoints, confidence = [], []
    for recording in recordings:
        _, candidates, candidate_confidence = aligned[recording.name]
        single_keypoints, single_confidence = _one_person(candidates, candidate_confidence)
        keypoints.append(single_keypoints)
        confidence.append(single_confidence)
    # Per camera, by name from every recording's detections.npz: image size and, where given, intrinsics.
    known: dict[str, dict[str, np.ndarray]] = {}
    for recording in recordings:
        if recording.npz is None:
            continue
        given = {key: getattr(recording.npz, key) for key in ("image_size", "K", "dist") if getattr(recording.npz, key) is not None}
        for index, camera in enumerate(recording.npz.camera_names):
            known.setdefault(camera, {key: array[index] for key, array in given.items()} | {"model": recording.npz.distortion_model})
    sizes = []
    for camera in camera_order:
        if "image_size" in known.get(camera, {}):
            sizes.append(np.asarray(known[camera]["image_size"], np.int64))
        elif config.image_size is not None:
            sizes.append(np.asarray(config.image_size, np.int64))
        else:
            raise DataFormatError(
                config.root,
                "a calibration file (project or recording folder, or --data.calibration), or the image size to recover"
                " the rig (--data.image-size W H, or 'image_size' in detections.npz)",
                f"no calibration and no image size of camera {camera!r}",
            )
    intrinsics = [known.get(camera, {}) for camera in camera_order]
    given_K = all("K" in fields for fields in intrinsics)
    given_dist = given_K and all("dist" in fields for fields in intrinsics)
    detections = RigDetections(
        keypoints=np.concatenate(keypoints),
        confidence=np.concatenate(confidence),
        camera_names=tuple(camera_order),
        image_size=np.stack(sizes),
        skeleton=skeleton,
        K=np.stack([fields["K"] for fields in intrinsics]).astype(np.float64) if given_K else None,
        dist=np.stack([fields["dist"] for fields in intrinsics]).astype(np.float64) if given_dist else None,
        distortion_model=intrinsics[0].get("model", "opencv"),
        source=f"{config.root} (all recordings)",
    )
    calibration = calibrate(detections, CalibrationConfig(max_frames=config.recovery_frames))
    rig = RigCalibration(
        camera_names=tuple(camera_order),
        cameras=calibration.cameras.replace(**{name: np.asarray(getattr(calibration.cameras, name), np.float64) for name in ("K", "R", "t")}),
        image_size=detections.image_size,
        source="recovered from the recordings by jaxpose.calibrate",
        unit="mm",
    )
    return rig, calibration


def _similarity(source: np.ndarray, target: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """(s, R, t) minimising |s R source + t - target| over corresponding points [M, 3] (Umeyama)."""
    mean_source, mean_target = source.mean(0), target.mean(0)
    a, b = source - mean_source, target - mean_target
    u, singular, vt = np.linalg.svd(b.T @ a / len(a))
    sign = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    R = u @ sign @ vt
    s = float(np.trace(np.diag(singular) @ sign) / a.var(0).sum())
    return s, R, mean_target - s * R @ mean_source


def _ground_truth_into_recovered_world(target: np.ndarray, keypoints, confidence, rig: RigCalibration) -> np.ndarray:
    """Ground truth [N, J, 3] in the motion capture's world, turned into the recovered rig's world.

    A recovered rig has its own world frame (`jaxpose.calibrate`), so the ground truth is moved there
    by the similarity that maps it best onto the triangulated detections (least squares, then again
    without the worst 10% of joints); only the rotation and translation are applied, so it keeps
    its true size: MPJPE then includes the recovered rig's scale error, P-MPJPE does not.
    """
    from jaxpose.triangulation import triangulate

    P = jnp.asarray(projection_matrices(rig.cameras.without_distortion()), jnp.float32)
    points = np.asarray(triangulate(P, jnp.asarray(keypoints), jnp.asarray(confidence), method="normal"))
    usable = np.isfinite(target).all(-1) & ((confidence > 0).sum(1) >= 2)
    if usable.sum() < MIN_ALIGNMENT_POINTS:
        raise DataFormatError(
            f"{GROUND_TRUTH_NPZ}, array 'frames'",
            f"at least {MIN_ALIGNMENT_POINTS} joints at frames seen by two or more cameras, to bring the ground truth into"
            " the recovered rig's frame",
            f"{int(usable.sum())}: do its frame numbers match the detections'?",
        )
    source, destination = target[usable].astype(np.float64), points[usable].astype(np.float64)
    s, R, t = _similarity(source, destination)
    residual = np.linalg.norm(s * source @ R.T + t - destination, axis=-1)
    keep = residual <= np.quantile(residual, 0.9)
    s, R, t = _similarity(source[keep], destination[keep])
    return (target @ R.T + t / s).astype(np.float32)


def load_rig_project(config: RigProjectConfig, progress: bool = True) -> RigProject:
    """Every recording of the project, read, aligned, calibrated and reduced to one person, split into
    training and validation parts (see the module docstring)."""
    recordings = [_read_recording(config, folder, progress) for folder in recording_folders(config.root, config.recordings)]
    layouts = {recording.name: recording.layout for recording in recordings}
    if len(set(layouts.values())) > 1:
        raise DataFormatError(config.root, "one keypoint layout in every recording", f"layouts {layouts}")
    layout = recordings[0].layout
    skeleton = lifting_skeleton(layout)
    project_calibration = _calibrations(config, recordings)
    present = set().union(*(recording.cameras for recording in recordings))
    if project_calibration is not None:
        camera_order = [name for name in project_calibration.camera_names if name in present]
    else:
        camera_order = sorted(present)
    for recording in recordings:
        if recording.calibration is not None:  # every detection folder needs its camera
            recording.calibration.select(sorted(recording.cameras), f"detection folders of recording {recording.name}")
    unknown_validation = sorted(set(config.validation_recordings) - {recording.name for recording in recordings})
    if unknown_validation:
        raise ValueError(f"--data.validation-recordings {unknown_validation}: no such recording (have {[r.name for r in recordings]})")
    given = parse_frame_offsets(config.frame_offsets, recordings)
    aligned = {}
    for recording in recordings:
        views = _lifting_views(recording, config)
        cameras = [camera for camera in camera_order if camera in views]
        if config.sync == "auto":
            recording.sync = _estimate_sync(recording, views, cameras, config)
            recording.offsets = dict(zip(cameras, recording.sync.offsets.tolist()))
            state = "" if recording.sync.reliable else " (UNRELIABLE: the person hardly moves between frames)"
            log.info("recording %s: estimated frame offsets %s%s", recording.name, recording.offsets, state)
        else:
            recording.offsets = {camera: given.get((recording.name, camera), 0) for camera in cameras}
        aligned[recording.name] = _align(views, camera_order, recording.offsets)
    recovered = None
    if project_calibration is None and all(recording.calibration is None for recording in recordings):
        rig, recovered = _recover_rig(config, recordings, aligned, camera_order, skeleton)
        for recording in recordings:
            recording.calibration = rig

    rigs, rig_keys, parts = [], {}, []
    ground_truth_seen = False
    summaries = []
    for recording in recordings:
        instants, candidates, candidate_confidence = aligned[recording.name]
        rig = _in_view_order(recording.calibration, camera_order)
        for index, camera in enumerate(camera_order):
            candidates[:, index] = _undistorted(rig, camera, candidates[:, index])
        pinhole = rig.cameras.without_distortion()
        choice = choose_person(np.asarray(projection_matrices(pinhole)), candidates, candidate_confidence, config.person_threshold_px)
        target, truth_instants = _ground_truth(recording.folder, skeleton, layout, instants)
        if target is not None and recovered is not None:
            target = _ground_truth_into_recovered_world(target, choice.keypoints, choice.confidence, rig)
        ground_truth_seen |= target is not None
        key = id(recording.calibration)
        if key not in rig_keys:
            rig_keys[key] = len(rigs)
            rigs.append(jax.tree.map(lambda field: np.asarray(field, np.float32), pinhole))
        parts.append((recording, instants, choice, target, rig_keys[key]))
        summaries.append(
            RecordingSummary(
                name=recording.name,
                cameras=tuple(camera for camera in camera_order if camera in recording.cameras),
                instants=len(instants),
                calibration=recording.calibration.source,
                offsets=dict(recording.offsets),
                offsets_estimated=recording.sync is not None,
                sync_reliable=None if recording.sync is None else recording.sync.reliable,
                instants_with_choice=choice.instants_with_choice,
                views_without_match=choice.views_without_match,
                ground_truth_instants=truth_instants,
            )
        )
    stacked_rigs = jax.tree.map(lambda *fields: np.stack(fields), *rigs)
    train, validation = [], []
    for recording, instants, choice, target, rig_index in parts:
        if target is None and ground_truth_seen:
            target = np.full((len(instants), skeleton.num_joints, 3), np.nan, np.float32)
        dataset = MultiViewDataset(
            skeleton=skeleton,
            keypoints2d=choice.keypoints,
            confidence=choice.confidence,
            rigs=stacked_rigs,
            rig_index=np.full(len(instants), rig_index, np.int32),
            target3d=target,
            labels={
                "subject": np.full(len(instants), f"rig{rig_index}"),
                "recording": np.full(len(instants), recording.name),
                "sequence": np.full(len(instants), recording.name),  # what motion metrics difference along
                "frame": instants.astype(np.int32),
            },
        ).with_own_context()
        position = np.arange(len(instants))
        if recording.name in config.validation_recordings:
            held_out = np.ones(len(instants), bool)
        elif config.validation_recordings:
            held_out = np.zeros(len(instants), bool)
        else:
            held_out = position >= int(round(len(instants) * (1.0 - config.validation_fraction)))
        train.append(dataset.subset(np.flatnonzero(~held_out & (position % config.train_stride == 0))))
        validation.append(dataset.subset(np.flatnonzero(held_out & (position % config.validation_stride == 0))))
    validation_set, train_set = concatenate(validation), concatenate(train)
    if train_set.target3d is not None and not np.isfinite(train_set.target3d).all():
        # Ground truth for only some joints or recordings serves evaluation, not the supervised twin.
        log.info("the ground truth does not cover every training instant and joint: no --supervision full")
        train_set = dataclasses.replace(train_set, target3d=None)
    return RigProject(
        train=train_set,
        validation=validation_set,
        camera_names=tuple(camera_order),
        layout=layout,
        recordings=tuple(summaries),
        ground_truth_joints=ground_truth.ground_truth_joint_names(validation_set) if ground_truth_seen else (),
        recovered_calibration=recovered,
    )

