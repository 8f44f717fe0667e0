"""The rig recovered from the recordings when a project has no calibration, and the ground truth
brought into its world.

`jaxpose.calibrate` recovers the rig from the person seen by every camera (the instants where each
view sees exactly one person), with the image sizes and any intrinsics the recordings'
detections.npz give; a project of several sessions has one rig per session (`jaxpose.rig.sessions`).  A recovered rig has its own world frame, so a ground truth in the motion
capture's world is moved into it for evaluation (`ground_truth_into_recovered_world`).
"""

from __future__ import annotations

import dataclasses
import logging
import pathlib
from collections.abc import Mapping, Sequence

import numpy as np

from jaxpose.camera import projection_matrices
from jaxpose.formats.rig_cameras import RigCalibration
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.rig_folder import GROUND_TRUTH_NPZ
from jaxpose.rig.geometry import triangulate_rows, undistort_views
from jaxpose.rotations import similarity
from jaxpose.rig.recordings import one_person
from jaxpose.skeleton import Skeleton

log = logging.getLogger(__name__)

MIN_ALIGNMENT_POINTS = 50  # ground-truth joints needed to align it with a recovered rig


def rig_detections(
    names: Sequence[str],
    known: Sequence[Mapping[str, dict]],
    aligned: Sequence[tuple[np.ndarray, np.ndarray]],
    camera_order: Sequence[str],
    skeleton: Skeleton,
    *,
    image_size: tuple[int, int] | None,
    root: pathlib.Path,
):
    """The detections `jaxpose.calibrate` recovers a rig from: the instants of some recordings (`aligned`:
    each recording's keypoints and confidence on one time axis, `jaxpose.rig.timeline.align`), each
    view's detection where it saw one person, one recording after the other; `known`: what each
    recording's detections.npz gives of its cameras (image size, intrinsics); `image_size`
    (--data.image-size) serves the cameras none gives one.  A `RigDetections`."""
    from jaxpose.calibration import RigDetections  # the calibrate extra

    keypoints, confidence = [], []
    for candidates, candidate_confidence in aligned:
        single_keypoints, single_confidence = one_person(candidates, candidate_confidence)
        keypoints.append(single_keypoints)
        confidence.append(single_confidence)
    # Per camera, by name from every recording's detections.npz: image size and, where given, intrinsics.
    given: dict[str, dict[str, np.ndarray]] = {}
    for cameras in known:
        for camera, fields in cameras.items():
            given.setdefault(camera, fields)
    sizes = []
    for camera in camera_order:
        if "image_size" in given.get(camera, {}):
            sizes.append(np.asarray(given[camera]["image_size"], np.int64))
        elif image_size is not None:
            sizes.append(np.asarray(image_size, np.int64))
        else:
            raise DataFormatError(
                root,
                "a calibration file (project or recording folder, or --data.calibration), or the image size to recover"
                " the rig (--data.image-size W H, or 'image_size' in detections.npz)",
                f"no calibration and no image size of camera {camera!r}",
            )
    intrinsics = [given.get(camera, {}) for camera in camera_order]
    given_K = all("K" in fields for fields in intrinsics)
    given_dist = given_K and all("dist" in fields for fields in intrinsics)
    return RigDetections(
        keypoints=np.concatenate(keypoints),
        confidence=np.concatenate(confidence),
        camera_names=tuple(camera_order),
        image_size=np.stack(sizes),
        skeleton=skeleton,
        K=np.stack([fields["K"] for fields in intrinsics]).astype(np.float64) if given_K else None,
        dist=np.stack([fields["dist"] for fields in intrinsics]).astype(np.float64) if given_dist else None,
        distortion_model=intrinsics[0].get("model", "opencv"),
        source=f"{root} (recording {names[0]}" + (f" and {len(names) - 1} more)" if len(names) > 1 else ")"),
    )


def recover_rig(detections, *, max_frames: int, height_mm: float | None = None):
    """`jaxpose.calibrate` on `detections` (`rig_detections`), on at most `max_frames` instants, the rig
    then moved into the person's upright metric world.  Returns (the rig as a `RigCalibration`, the
    `jaxpose.calibration.Calibration`)."""
    from jaxpose.calibration import CalibrationConfig, calibrate  # the calibrate extra

    calibration = calibrate(detections, CalibrationConfig(max_frames=max_frames))
    calibration = _upright(calibration, detections, detections.skeleton, height_mm)
    rig = RigCalibration(
        camera_names=tuple(detections.camera_names),
        cameras=calibration.cameras.replace(**{name: np.asarray(getattr(calibration.cameras, name), np.float64) for name in ("K", "R", "t")}),
        image_size=detections.image_size,
        source="recovered from the recordings by jaxpose.calibrate",
        unit="mm",
    )
    return rig, calibration


def _upright(calibration, detections, skeleton: Skeleton, height_mm: float | None):
    """`calibration` with its cameras moved into the upright metric world of the person
    (`jaxpose.calibration.world`: +Y up, the floor at Y = 0, mm; scaled by `height_mm` where given), so that
    the project's motion stands on the floor; where the person does not show it (a `ValueError` of
    `world_frame`), view 0's frame is kept and the log says why."""
    from jaxpose.calibration.world import WORLD_FRAME, cameras_to_world, world_frame

    names = calibration.camera_names
    rig = RigCalibration(camera_names=names, cameras=calibration.cameras, image_size=detections.image_size, source="recovered", unit="mm")
    keypoints = np.stack([undistort_views(rig, name, detections.keypoints[:, c]) for c, name in enumerate(names)], 1)
    P = np.asarray(projection_matrices(calibration.cameras.without_distortion()), np.float32)
    points = triangulate_rows(P, keypoints, detections.confidence, method="normal")
    valid = (detections.confidence > 0).sum(1) >= 2
    try:
        world = world_frame(points, valid, skeleton, height_mm=height_mm)
    except ValueError as error:
        log.warning("the recovered rig stays in view 0's camera frame (not upright): %s", error)
        return calibration
    log.info(
        "recovered rig moved into the %s (up from the %s, scale from the %s, x%.3f)", WORLD_FRAME, world.up_source, world.scale_source, world.scale
    )
    return dataclasses.replace(calibration, cameras=cameras_to_world(world, calibration.cameras))


def ground_truth_into_recovered_world(target: np.ndarray, keypoints, confidence, rig: RigCalibration) -> np.ndarray:
    """Ground truth [N, J, 3] in the motion capture's world, turned into the recovered rig's world.

    A recovered rig has its own world frame (`jaxpose.calibrate`), so the ground truth is moved there
    by the similarity that maps it best onto the triangulated detections (least squares, then again
    without the worst 10% of joints); only the rotation and translation are applied, so it keeps
    its true size: MPJPE then includes the recovered rig's scale error, P-MPJPE does not.
    """
    P = np.asarray(projection_matrices(rig.cameras.without_distortion()), np.float32)
    points = triangulate_rows(P, keypoints, confidence, method="normal")
    usable = np.isfinite(target).all(-1) & ((confidence > 0).sum(1) >= 2)
    if usable.sum() < MIN_ALIGNMENT_POINTS:
        raise DataFormatError(
            f"{GROUND_TRUTH_NPZ}, array 'frames'",
            f"at least {MIN_ALIGNMENT_POINTS} joints at frames seen by two or more cameras, to bring the ground truth into"
            " the recovered rig's frame",
            f"{int(usable.sum())}: do its frame numbers match the detections'?",
        )
    source, destination = target[usable].astype(np.float64), points[usable].astype(np.float64)
    s, R, t = similarity(source, destination)
    residual = np.linalg.norm(s * source @ R.T + t - destination, axis=-1)
    keep = residual <= np.quantile(residual, 0.9)
    s, R, t = similarity(source[keep], destination[keep])
    return (target @ R.T + t / s).astype(np.float32)
