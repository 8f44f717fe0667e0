"""The rig of each recording of a project: the calibration files found (the project's, a recording's
own, or --data.calibration), their cameras matched to the detection folders by name, put in the data
set's view order, and the keypoints undistorted with them.
"""

from __future__ import annotations

import dataclasses
import pathlib
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.camera import undistort_points
from jaxpose.formats.calibrated_rig import CalibrationUnit, RigCalibration
from jaxpose.formats.camera_names import CameraMismatch, match_cameras
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.rig_calibration import find_calibration, read_rig_calibration
from jaxpose.rig.recordings import Recording


def _named_as_detections(calibration: RigCalibration, detection_names: set[str]) -> RigCalibration:
    """The calibration with its cameras named as the detection folders, matched as
    `jaxpose.formats.camera_names.match_cameras` matches them (Pose2Sim's `int_cam01_img` or `cam_01` is
    the camera of its `cam01_json` folder; by order, as Pose2Sim pairs them, where no name matches at all);
    where they do not match one to one, the calibration as it is: `RigCalibration.select` reports it."""
    try:
        matched = match_cameras(calibration.camera_names, sorted(detection_names), calibration.source, by_order=True)
    except CameraMismatch:
        return calibration
    name_of = {camera: name for name, camera in matched.items()}
    renamed = tuple(name_of.get(camera, camera) for camera in calibration.camera_names)
    return dataclasses.replace(calibration, camera_names=renamed)


def attach_calibrations(
    recordings: Sequence[Recording], root: pathlib.Path, calibration: pathlib.Path | None, unit: CalibrationUnit
) -> RigCalibration | None:
    """Attach each recording's calibration: its own file, else `calibration` (--data.calibration), else
    the file found in the project folder `root`.  Returns the project-wide one (None: none anywhere)."""
    project_file = calibration or find_calibration(root)
    project = None if project_file is None else read_rig_calibration(project_file, unit)
    if project is not None:
        project = _named_as_detections(project, set().union(*(recording.cameras for recording in recordings)))
    for recording in recordings:
        own = find_calibration(recording.folder)
        if own is None:
            recording.calibration = project
        else:
            recording.calibration = _named_as_detections(read_rig_calibration(own, unit), set(recording.cameras))
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
        raise DataFormatError(root, "a calibration for every recording, or for none", f"none for recordings {missing}")
    return project


def in_view_order(calibration: RigCalibration, camera_order: Sequence[str]) -> RigCalibration:
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


def undistorted(calibration: RigCalibration | None, camera: str, keypoints: np.ndarray) -> np.ndarray:
    """Keypoints [..., 2] of `camera` undistorted with `calibration` (as they are without a calibration or distortion)."""
    if calibration is None or calibration.cameras.dist is None:
        return keypoints
    index = calibration.camera_names.index(camera)
    cameras = jax.tree.map(lambda field: jnp.asarray(field[index], jnp.float32), calibration.cameras)
    flat = keypoints.reshape(-1, 2)
    return np.asarray(undistort_points(cameras, jnp.asarray(flat))).reshape(keypoints.shape)
