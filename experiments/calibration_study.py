"""Rig calibration from the person on the synthetic data set, where every rig and body is known.

    python -m experiments.calibration_study                        # every subject, intrinsics given (~3 min on 2 cores)
    python -m experiments.calibration_study --unknown-intrinsics   # focal lengths estimated too

Each subject of the default synthetic data set (its own rig: the room's cameras with a small
per-subject jitter; the default detector with its noise, outliers and left/right swaps) is
calibrated alone by `jaxpose.calibration.calibrate` and compared with its true rig after a
similarity alignment.  Columns: the worst camera's rotation error and centre error (mm, and as a
share of that camera's distance to the subject), the scale error, and the scale error the limb
prior implies for this body (prior / the body's true limb lengths - 1; the scale can be no better
than the prior), the median re-projection error and the time.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import tyro

from jaxpose.calibration import CalibrationConfig, calibrate, compare_rigs, from_dataset
from jaxpose.camera import camera_centres
from jaxpose.calibration.scale import prior_scale_error
from jaxpose.synthetic import SyntheticConfig, generate


@dataclasses.dataclass(frozen=True)
class Args:
    """Calibrate every synthetic subject's rig from its detections and compare with the truth."""

    generator: SyntheticConfig = SyntheticConfig()
    """The synthetic data set (its defaults are the main job's)."""
    calibration: CalibrationConfig = CalibrationConfig()
    """How the rigs are recovered."""
    unknown_intrinsics: bool = False
    """Withhold K: estimate the focal lengths from the image-size guess."""


def main(argv=None) -> list[dict]:
    args = tyro.cli(Args, args=argv, prog="python -m experiments.calibration_study", description=__doc__.split("\n\n")[0])
    dataset = generate(args.generator)
    names = tuple(f"camera{c}" for c in range(dataset.num_views))
    image_size = np.tile(np.asarray(args.generator.image_size), (dataset.num_views, 1))
    print(
        "| subject | rotation error, max (deg) | centre error, max (mm) | centre error, max (% of distance) |"
        " scale error | prior's scale error | re-projection median (px) | time (s) |\n|---|---|---|---|---|---|---|---|"
    )
    rows = []
    for subject in dict.fromkeys(dataset.samples.labels["subject"].tolist()):
        of_subject = dataset.where(subject=[subject])
        rig = of_subject.rigs[int(of_subject.samples.rig_index[0])]
        R, t = np.asarray(rig.R, np.float64), np.asarray(rig.t, np.float64)
        detections = from_dataset(of_subject, subject, names, image_size)
        detections = detections.without_intrinsics() if args.unknown_intrinsics else detections
        calibration = calibrate(detections, args.calibration)
        comparison = compare_rigs(calibration.cameras.R, calibration.cameras.t, R, t)
        distance = np.linalg.norm(camera_centres(R, t) - np.median(of_subject.samples.target3d[:, 0], axis=0), axis=-1)
        row = {
            "subject": subject,
            "rotation_deg": float(comparison.rotation_deg.max()),
            "centre_mm": float(comparison.centre_mm.max()),
            "centre_share": float((comparison.centre_mm / distance).max()),
            "scale_error": comparison.scale_error,
            "prior_scale_error": prior_scale_error(of_subject.samples.target3d, of_subject.skeleton, args.calibration.limb_lengths_mm),
            "reprojection_px": float(np.median(calibration.reprojection_median_px)),
            "seconds": calibration.seconds,
        }
        rows.append(row)
        print(
            f"| {subject} | {row['rotation_deg']:.3f} | {row['centre_mm']:.1f} | {row['centre_share']:.2%} |"
            f" {row['scale_error']:+.2%} | {row['prior_scale_error']:+.2%} | {row['reprojection_px']:.2f} | {row['seconds']:.0f} |",
            flush=True,
        )
    return rows


if __name__ == "__main__":
    main()
