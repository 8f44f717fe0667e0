"""The rig of each recording of a project: the calibration files found (the project's, a recording's
own, or --data.calibration), their cameras matched to the detection folders by name, put in the data
set's view order, and their unit checked against the people in view.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import pathlib
from collections.abc import Mapping, Sequence

import numpy as np

from jaxpose.formats.rig_cameras import (
    MM_PER_UNIT,
    UNIT_FLAG,
    CalibrationUnit,
    RigCalibration,
)
from jaxpose.formats.camera_names import CameraMismatch, match_cameras
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.calibration_files import read_rig_calibration
from jaxpose.rig.recordings import FoundProject
from jaxpose.skeleton import Skeleton

log = logging.getLogger(__name__)
UNIT_TOLERANCE = 1.5  # an adult's limbs are the prior's within this factor


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


def read_calibrations(project_files: FoundProject, unit: CalibrationUnit) -> tuple[RigCalibration | None, dict[str, RigCalibration | None]]:
    """Each recording's calibration: its own file, else the project's (`FoundProject.calibration`).  Returns
    the project-wide one (None: none anywhere) and each recording's by name (None for all: the rig is to be
    recovered)."""
    recordings = project_files.recordings
    project = None if project_files.calibration is None else read_rig_calibration(project_files.calibration, unit)
    if project is not None:
        project = _named_as_detections(project, set().union(*(recording.cameras for recording in recordings)))
    found: dict[str, RigCalibration | None] = {}
    for recording in recordings:
        own = recording.calibration
        found[recording.name] = project if own is None else _named_as_detections(read_rig_calibration(own, unit), set(recording.cameras))
    if project is not None:
        used = set().union(*(recording.cameras for recording in recordings if found[recording.name] is project))
        unused = [name for name in project.camera_names if name not in used]
        if unused and used:
            raise DataFormatError(
                project.source,
                f"a detection folder for each of its cameras {list(project.camera_names)}",
                f"cameras {unused} have no detections in any recording (detection folders: {sorted(used)})",
            )
    missing = [name for name, rig in found.items() if rig is None]
    if missing and len(missing) < len(recordings):
        raise DataFormatError(project_files.root, "a calibration for every recording, or for none", f"none for recordings {missing}")
    return project, found


def distinct_rigs(calibrations: Mapping[str, RigCalibration]) -> tuple[list[RigCalibration], dict[str, int]]:
    """The distinct rigs of the recordings (`calibrations`: recording -> its rig), in order of first use, and
    each recording's index among them; rigs are told apart by their content (source, cameras, K, R, t)."""
    rigs: list[RigCalibration] = []
    index_of: dict[tuple, int] = {}
    indices = {}
    for name, rig in calibrations.items():
        key = (rig.source, rig.camera_names, *(np.asarray(getattr(rig.cameras, field)).tobytes() for field in ("K", "R", "t")))
        if key not in index_of:
            index_of[key] = len(rigs)
            rigs.append(rig)
        indices[name] = index_of[key]
    return rigs, indices


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


def check_unit_against_people(calibration: RigCalibration, points: np.ndarray, reliable: np.ndarray, skeleton: Skeleton) -> str | None:
    """Refuse a calibration whose unit makes the people in view 10, 100 or 1000 times too small or large.

    A file that states no unit is read in metres or millimetres by the rig's size (`--data.calibration-unit
    auto`); a rig in centimetres then reads as millimetres, trains, and reports errors ten times too large.
    The people in view know better: their limbs (upper arm, forearm, thigh, shank: `jaxpose.calibration.scale`),
    triangulated through the rig as read (`points` f[N, J, 3] mm, `reliable` bool[N, J]), are an adult's
    within a factor `UNIT_TOLERANCE`.  Off by a power of ten (within that factor) is a wrong unit: stop,
    naming the file and the flag; off by another factor is logged and returned, for the report (a child, or a
    poor calibration).
    """
    try:
        from jaxpose.calibration.scale import metric_scale  # the calibrate extra
    except ImportError:
        log.warning("%s: its unit was not checked against the people in view (needs pip install 'jaxpose[calibrate]')", calibration.source)
        return None
    try:
        scale = metric_scale(points, reliable, skeleton)
    except ValueError:
        return None  # no limb triangulated: nothing to compare with
    factor = scale.mm_per_unit  # the prior over the measured lengths
    if 1.0 / UNIT_TOLERANCE <= factor <= UNIT_TOLERANCE:
        return None
    limbs = ", ".join(f"{limb} {length / factor:.0f}" for limb, length in scale.measured_mm.items())
    adult = ", ".join(f"{limb} {length:.0f}" for limb, length in scale.prior_mm.items())
    power = round(math.log10(factor))
    if power == 0 or abs(math.log10(factor) - power) > math.log10(UNIT_TOLERANCE):
        warning = f"{calibration.source}: the people in view have limbs of {limbs} mm where an adult's are {adult} mm: is the calibration right?"
        log.warning("%s", warning)
        return warning
    mm_per_unit = MM_PER_UNIT[calibration.unit] * factor
    likely = min(MM_PER_UNIT, key=lambda unit: abs(math.log10(MM_PER_UNIT[unit] / mm_per_unit)))
    raise DataFormatError(
        calibration.source,
        f"people of an adult's size (limbs {adult} mm) when read in {calibration.unit!r}",
        f"limbs of {limbs} mm, {factor:.3g} times too {'short' if factor > 1 else 'long'}: the file is likely in"
        f" {likely!r}; say its unit with {UNIT_FLAG} m|cm|mm",
    )
