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
1. reads every camera's detections (parsed once, then cached: `jaxpose.formats.keypoint_files`),
   and finds its calibration (`jaxpose.rig.recordings`, `jaxpose.rig.calibrations`);
2. converts them from the detector's layout to its lifting skeleton (the detector's own joints,
   root first: `jaxpose.layouts.to_lifting_skeleton`); scores below `min_confidence` are
   treated as missing;
3. aligns the cameras in time: camera c's frame f shows instant f + offset[c]; offsets given, or
   estimated (`jaxpose.rig.timeline`, `jaxpose.rig.sync`); instants seen by no camera are absent, a
   camera without a frame at an instant has confidence 0 there;
4. without any calibration, recovers the rig from all recordings (`jaxpose.rig.recovered`);
5. undistorts the keypoints with the calibration (the data sets' rigs are then pinhole);
6. keeps one person per instant, the one the views agree on (`jaxpose.rig.people`);
7. attaches the ground truth where there is one, over the joints it shares with the lifting
   skeleton by name (the derived root from the hips where the ground truth has both:
   `jaxpose.data.ground_truth`), moved into a recovered rig's world.
"""

from __future__ import annotations

import dataclasses
import logging
import pathlib
from collections.abc import Sequence
from typing import Literal

import jax
import numpy as np

from jaxpose.camera import projection_matrices
from jaxpose.data import ground_truth
from jaxpose.data.dataset import MultiViewDataset, concatenate
from jaxpose.formats.calibrated_rig import CalibrationUnit
from jaxpose.formats.errors import DataFormatError
from jaxpose.layouts import lifting_skeleton
from jaxpose.rig.calibrations import attach_calibrations, in_view_order, undistorted
from jaxpose.rig.people import DEFAULT_THRESHOLD_PX, choose_person
from jaxpose.rig.recordings import Recording, ground_truth_on_instants, lifting_views, read_recording, recording_folders
from jaxpose.rig.recovered import ground_truth_into_recovered_world, recover_rig
from jaxpose.rig.timeline import align, estimate_recording_offsets, parse_frame_offsets

log = logging.getLogger(__name__)


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


def load_rig_project(config: RigProjectConfig, progress: bool = True) -> RigProject:
    """Every recording of the project, read, aligned, calibrated and reduced to one person, split into
    training and validation parts (see the module docstring)."""
    recordings = [read_recording(folder, config.skeleton, progress) for folder in recording_folders(config.root, config.recordings)]
    layouts = {recording.name: recording.layout for recording in recordings}
    if len(set(layouts.values())) > 1:
        raise DataFormatError(config.root, "one keypoint layout in every recording", f"layouts {layouts}")
    layout = recordings[0].layout
    skeleton = lifting_skeleton(layout)
    project_calibration = attach_calibrations(recordings, config.root, config.calibration, config.calibration_unit)
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
    aligned = _on_one_time_axis(config, recordings, camera_order)
    recovered_calibration = None
    if project_calibration is None and all(recording.calibration is None for recording in recordings):
        rig, recovered_calibration = recover_rig(
            recordings, aligned, camera_order, skeleton,
            image_size=config.image_size, max_frames=config.recovery_frames, root=config.root,
        )  # fmt: skip
        for recording in recordings:
            recording.calibration = rig

    rigs, rig_keys, parts = [], {}, []
    ground_truth_seen = False
    summaries = []
    for recording in recordings:
        instants, candidates, candidate_confidence = aligned[recording.name]
        rig = in_view_order(recording.calibration, camera_order)
        for index, camera in enumerate(camera_order):
            candidates[:, index] = undistorted(rig, camera, candidates[:, index])
        pinhole = rig.cameras.without_distortion()
        choice = choose_person(np.asarray(projection_matrices(pinhole)), candidates, candidate_confidence, config.person_threshold_px)
        target, truth_instants = ground_truth_on_instants(recording.folder, skeleton, layout, instants)
        if target is not None and recovered_calibration is not None:
            target = ground_truth_into_recovered_world(target, choice.keypoints, choice.confidence, rig)
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
        held_out, position = _held_out(config, recording.name, len(instants)), np.arange(len(instants))
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
        recovered_calibration=recovered_calibration,
    )


def _on_one_time_axis(
    config: RigProjectConfig, recordings: Sequence[Recording], camera_order: Sequence[str]
) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Each recording's lifting views on one time axis (`jaxpose.rig.timeline.align`), by recording
    name; sets each recording's offsets (given, or estimated with --data.sync auto)."""
    given = parse_frame_offsets(config.frame_offsets, recordings)
    aligned = {}
    for recording in recordings:
        views = lifting_views(recording, config.min_confidence)
        cameras = [camera for camera in camera_order if camera in views]
        if config.sync == "auto":
            recording.sync = estimate_recording_offsets(recording, views, cameras, config.max_sync_offset)
            recording.offsets = dict(zip(cameras, recording.sync.offsets.tolist()))
            state = "" if recording.sync.reliable else " (UNRELIABLE: the person hardly moves between frames)"
            log.info("recording %s: estimated frame offsets %s%s", recording.name, recording.offsets, state)
        else:
            recording.offsets = {camera: given.get((recording.name, camera), 0) for camera in cameras}
        aligned[recording.name] = align(views, camera_order, recording.offsets)
    return aligned


def _held_out(config: RigProjectConfig, recording: str, instants: int) -> np.ndarray:
    """bool[instants]: which of a recording's instants validate (--data.validation-recordings, else the
    final --data.validation-fraction of each recording)."""
    if recording in config.validation_recordings:
        return np.ones(instants, bool)
    if config.validation_recordings:
        return np.zeros(instants, bool)
    return np.arange(instants) >= int(round(instants * (1.0 - config.validation_fraction)))
