"""A recording's cameras on one time axis.

Camera c's frame f shows instant f + offset[c]; the offsets are given (--data.frame-offsets, parsed
here) or estimated from the detections (`jaxpose.rig.sync`).  Instants seen by no camera are absent,
and a camera without a frame at an instant has confidence 0 there.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence

import numpy as np

from jaxpose.camera import projection_matrices
from jaxpose.formats.rig_cameras import RigCalibration
from jaxpose.rig.geometry import undistort_views
from jaxpose.rig.recordings import Recording, Views, one_person
from jaxpose.rig.sync import SyncEstimate, estimate_offsets


def parse_frame_offsets(values: Sequence[str], recordings: Sequence[Recording]) -> dict[tuple[str, str], int]:
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


def estimate_recording_offsets(
    recording: Recording, calibration: RigCalibration | None, views: Views, camera_order: Sequence[str], max_offset: int
) -> SyncEstimate:
    """`jaxpose.rig.sync.estimate_offsets` on the frames where each camera sees one person (offsets up
    to `max_offset` frames), with the recording's `calibration` where it has one."""
    frames, keypoints, confidence = [], [], []
    for camera in camera_order:
        camera_frames, camera_keypoints, camera_confidence = views[camera]
        single_keypoints, single_confidence = one_person(camera_keypoints, camera_confidence)
        rows = np.flatnonzero((single_confidence > 0).any(-1))
        frames.append(camera_frames[rows])
        keypoints.append(undistort_views(calibration, camera, single_keypoints[rows]))
        confidence.append(single_confidence[rows])
    projections = None
    if calibration is not None:
        rig = calibration.select(camera_order, f"cameras of recording {recording.name}")
        projections = np.asarray(projection_matrices(rig.cameras.without_distortion()), np.float64)
    return estimate_offsets(frames, keypoints, confidence, projections, max_offset, camera_names=list(camera_order))


def instants_of(views: Views, offsets: Mapping[str, int]) -> np.ndarray:
    """int[N] the recording's instants: every camera's frames moved by its offset, sorted, unique."""
    return np.unique(np.concatenate([frames + offsets.get(camera, 0) for camera, (frames, _, _) in views.items()]))


def lone_cameras(views: Views, offsets: Mapping[str, int]) -> list[str]:
    """The cameras none of whose frames shows an instant another camera shows (with their offsets): their
    detections can be neither triangulated nor paired; usually a frame offset that is wrong."""
    shown = {camera: np.unique(frames + offsets.get(camera, 0)) for camera, (frames, _, _) in views.items()}
    lone = []
    for camera, instants in shown.items():
        others = [other for name, other in shown.items() if name != camera]
        if others and len(instants) and not np.isin(instants, np.concatenate(others)).any():
            lone.append(camera)
    return lone


def align(views: Views, camera_order: Sequence[str], offsets: Mapping[str, int], instants: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The cameras on one time axis at `instants` (sorted, some or all of `instants_of`): keypoints
    [n, C, P, J, 2], confidence [n, C, P, J]."""
    people = max(views[c][1].shape[1] for c in views)
    J = next(iter(views.values()))[1].shape[2]
    keypoints = np.zeros((len(instants), len(camera_order), people, J, 2), np.float32)
    confidence = np.zeros((len(instants), len(camera_order), people, J), np.float32)
    for index, camera in enumerate(camera_order):
        if camera not in views:
            continue  # a camera this recording lacks: confidence 0 throughout
        frames, camera_keypoints, camera_confidence = views[camera]
        shown = frames + offsets.get(camera, 0)
        rows = np.minimum(np.searchsorted(instants, shown), len(instants) - 1)
        kept = np.flatnonzero(instants[rows] == shown)
        width = camera_keypoints.shape[1]
        keypoints[rows[kept], index, :width] = camera_keypoints[kept]
        confidence[rows[kept], index, :width] = camera_confidence[kept]
    return keypoints, confidence
