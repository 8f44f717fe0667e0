"""A recovered rig as a calibration file other tools open: the Anipose/Pose2Sim TOML layout.

    write_recovered_rig("calibration.toml", calibration)      # metres, as Pose2Sim reads them

One `[cam_<i>]` table per camera (name, size [W, H], matrix, distortions k1 k2 p1 p2 k3, rotation
as a Rodrigues vector, translation, fisheye = false) and a `[metadata]` table that says what the file
is: the translations' `unit`, the `world` frame the rig is in (`Calibration.world`: view 0's camera frame
from `calibrate` alone, or the upright world of `jaxpose.calibration.world.to_world`), where the rig came
from, each camera's re-projection error and how the scale was set.  Pose2Sim, Anipose and FreeMoCap read the camera tables and skip
`[metadata]`; jaxpose reads the unit from it.  No pickle anywhere: the file is plain TOML.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np

from jaxpose.calibration import WORLD_FRAME, Calibration
from jaxpose.calibration.world import WORLD_FRAME as UPRIGHT_WORLD_FRAME
from jaxpose.formats.anipose_toml import write_anipose_toml
from jaxpose.formats.rig_cameras import RigCalibration

SOURCE = "recovered from the person by jaxpose.calibrate (no calibration target)"


def recovered_rig(calibration: Calibration) -> RigCalibration:
    """The recovered cameras as a `RigCalibration` (float64, t mm), in the world they are in (`Calibration.world`)."""
    cameras = calibration.cameras.replace(**{name: np.asarray(getattr(calibration.cameras, name), np.float64) for name in ("K", "R", "t")})
    return RigCalibration(
        camera_names=tuple(calibration.camera_names),
        cameras=cameras,
        image_size=np.asarray(calibration.image_size, np.int64),
        source=SOURCE,
        unit="mm",
    )


def world_and_scale(calibration: Calibration) -> tuple[str, str]:
    """(the world the recovered rig is in, how its scale was set), from `Calibration.world`: the one statement
    of both, for its files and reports."""
    world = calibration.world
    if world is None or world.scale_source == "rig":
        limbs = ", ".join(f"{limb} {length:g} mm" for limb, length in calibration.scale.prior_mm.items())
        scale = f"limb prior ({limbs})"
    else:
        scale = {"height": "the subject's height", "limbs": "the subject's limb lengths"}[world.scale_source]
    return (WORLD_FRAME if world is None else UPRIGHT_WORLD_FRAME), scale


def rig_metadata(calibration: Calibration) -> dict:
    """What `[metadata]` says of a recovered rig, besides its unit: the world it is in and how its scale was set."""
    world, scale = world_and_scale(calibration)
    metadata = {
        "source": SOURCE,
        "world": world,
        "scale": scale,
        "reprojection_median_px": np.round(calibration.reprojection_median_px, 3).tolist(),
        "reprojection_p90_px": np.round(calibration.reprojection_p90_px, 3).tolist(),
        "focal_estimated": bool(calibration.focal_estimated),
    }
    if calibration.world is not None:
        metadata["up"] = {"floor": "normal of the floor the ankles stand on", "body": "the subject's body axis"}[calibration.world.up_source]
        metadata["ankle_height_mm"] = calibration.world.ankle_height_mm
    return metadata


def write_recovered_rig(
    path: str | Path,
    calibration: Calibration,
    *,
    unit: Literal["m", "mm"] = "m",
    overwrite: bool = False,
) -> Path:
    """Write the recovered rig (in the world it is in, `Calibration.world`) as an Anipose/Pose2Sim calibration TOML; returns `path`.

    Atomic; an existing file only with `overwrite` (`jaxpose.formats.outputs.OutputError`)."""
    write_anipose_toml(path, recovered_rig(calibration), unit, metadata=rig_metadata(calibration), overwrite=overwrite)
    return Path(path)
