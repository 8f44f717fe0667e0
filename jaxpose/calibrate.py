"""Recover a camera rig from the person it films, and write it as a jaxpose camera file.

    python -m jaxpose.calibrate --input detections.npz --output cameras.json
    python -m jaxpose.calibrate --input data/h36m --subject S1 --output s1_cameras.json \\
        --reference data/h36m/cameras.h5                       # a Human3.6M subject, checked against its calibration

Input: an ``.npz`` of synchronized multi-view detections (arrays: see `jaxpose.formats.detections_npz`),
or a Human3.6M data folder (the h36m.zip tree), of which `--subject` is read with `--detections`.
Output: the camera file (K, R, t in mm, dist as given; world frame and scale in its "comment"), a
report (`<output>.md`, also printed) with each camera's re-projection error and, with
`--reference`, its rotation and centre error after a similarity alignment, and a figure of the
recovered rig (`<output>.png`), beside the reference when there is one.  Train on it unchanged:
`python -m experiments.h36m --data.cameras-path cameras.json`.  None of the three files is written over
without --overwrite, nor an input ever; each is written to a temporary name renamed into place.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
import numpy as np
import tyro

from jaxpose import viz
from jaxpose.calibration import (
    WORLD_FRAME, Calibration, CalibrationConfig, RigComparison, RigDetections, calibrate, compare_rigs, from_dataset,
    read_detections_npz,
)  # fmt: skip
from jaxpose.calibration.rig_file import world_and_scale
from jaxpose.camera import Cameras, camera_centres
from jaxpose.compilation_cache import enable_compilation_cache
from jaxpose.formats.camera_file import read_calibration, save_cameras, select_views
from jaxpose.formats.outputs import atomic_output, check_output
from jaxpose.formats.h36m_cameras import H36M_IMAGE_SIZES
from jaxpose.datasets.h36m import CAMERA_NAMES, load_h36m


@dataclasses.dataclass(frozen=True)
class CalibrateArgs:
    """Recover a multi-camera rig from the detections of the person it films."""

    input: Path
    """An .npz of multi-view detections (keypoints [N, C, J, 2] px, or [N, C, P, J, 2] with several people per view;
    camera_names, image_size, skeleton;
    optional confidence, K, dist, distortion_model), or a Human3.6M data folder (h36m.zip tree)."""
    output: Path
    """The camera file to write (.json); the report and figure go beside it (<output>.md, <output>.png)."""
    subject: str = "S1"
    """Subject name in the written file; with a Human3.6M folder also the subject whose detections are read."""
    detections: str = "sh"
    """Human3.6M folder only: the 2D source (sh, cpn, gt, or a VideoPose3D-style 2D .npz)."""
    stride: int = 5
    """Human3.6M folder only: keep every n-th frame of the 50 fps sequences."""
    unknown_intrinsics: bool = False
    """Ignore the input's K and dist and estimate the focal lengths from an image-size guess (the
    uncalibrated case, e.g. to test it on data whose intrinsics are known)."""
    reference: Path | None = None
    """A calibration to compare with: cameras.h5 or a jaxpose camera file (errors after similarity alignment)."""
    reference_subject: str | None = None
    """The reference's subject to compare with (default: --subject)."""
    calibration: CalibrationConfig = CalibrationConfig()
    """How the rig is recovered (scale prior, frames, robust thresholds)."""
    overwrite: bool = False
    """Replace existing output files (the camera file, its report and figure); without it the command stops
    before any work.  An input (--input, --reference) is never replaced."""


def read_input(args: CalibrateArgs) -> RigDetections:
    """The detections of an .npz, or of one subject of a Human3.6M folder (with its known intrinsics)."""
    if args.input.is_dir():
        dataset = load_h36m(args.input, detections=args.detections, subjects=(args.subject,),
                            train_stride=args.stride, test_stride=args.stride)  # fmt: skip
        sizes = np.array([H36M_IMAGE_SIZES[name] for name in CAMERA_NAMES])
        detections = from_dataset(dataset, args.subject, CAMERA_NAMES, sizes, source=str(args.input))
    else:
        detections = read_detections_npz(args.input, people=args.calibration)  # several people: matched across views
    return detections.without_intrinsics() if args.unknown_intrinsics else detections


def read_reference(path: Path, subject: str, camera_names: Sequence[str]) -> Cameras:
    """The reference rig of `subject`, in the order of `camera_names`."""
    return select_views(read_calibration(path), path, subject, tuple(camera_names))


def report(calibration: Calibration, comparison: RigComparison | None, reference: Cameras | None) -> str:
    """The calibration report as markdown."""
    estimated = (calibration.lens.state != "held").any()
    intrinsics = "estimated intrinsics" if estimated else "given intrinsics"
    scale = calibration.scale
    world, scale_set = world_and_scale(calibration)  # the world the rig is in: moved into the upright one, or not
    lines = [
        f"# Rig recovered from the person ({len(calibration.camera_names)} cameras, {intrinsics})",
        "",
        f"{calibration.frames_used} frames, {calibration.seconds:.1f} s. World frame: {world}.",
        "Scale from the limb prior: "
        + ", ".join(f"{limb} {scale.prior_mm[limb]:.0f} mm (measured {length:.0f})" for limb, length in scale.measured_mm.items())
        + "."
        if calibration.world is None or calibration.world.scale_source == "rig"
        else f"Scale from {scale_set} (x{calibration.world.scale:.3f} the limb prior's).",
        "",
    ]
    header = "| camera | focal (px) | re-projection median (px) | 90th percentile (px) | detections kept |"
    rule = "|---|---|---|---|---|"
    if comparison is not None:
        header += " rotation error (deg) | centre error (mm) | reference focal (px) |"
        rule += "---|---|---|"
    lines += [header, rule]
    for c, name in enumerate(calibration.camera_names):
        row = (
            f"| {name} | {calibration.cameras.K[c, 0, 0]:.1f} | {calibration.reprojection_median_px[c]:.2f} |"
            f" {calibration.reprojection_p90_px[c]:.2f} | {calibration.inlier_fraction[c]:.1%} |"
        )
        if comparison is not None:
            row += f" {comparison.rotation_deg[c]:.3f} | {comparison.centre_mm[c]:.1f} | {float(reference.K[c, 0, 0]):.1f} |"
        lines.append(row)
    if estimated:
        lines += [
            "",
            "Intrinsics with their 1-sigma uncertainty; (prior): the detections do not determine it beyond its prior,"
            " so it stays at the prior's mean (the image-size guess of the focal length, the image centre, no distortion):",
            "",
            calibration.lens.summary(calibration.camera_names),
        ]
    if comparison is not None:
        lines += [
            "",
            f"Against the reference, after a similarity alignment: rotation error max {comparison.rotation_deg.max():.3f} deg,"
            f" centre error max {comparison.centre_mm.max():.1f} mm, scale error {comparison.scale_error:+.2%}"
            " (the recovered rig's size relative to the reference's).",
        ]
    return "\n".join(lines) + "\n"


def run(args: CalibrateArgs) -> tuple[Calibration, RigComparison | None]:
    if args.output.suffix != ".json":
        raise ValueError(f"--output {args.output}: a jaxpose camera file ends in .json")
    inputs = [args.input] + ([args.reference] if args.reference is not None else [])
    for path in (args.output, args.output.with_suffix(".md"), args.output.with_suffix(".png")):
        check_output(path, args.overwrite, inputs)
    detections = read_input(args)
    calibration = calibrate(detections, args.calibration)
    comment = (
        f"Recovered by jaxpose.calibrate from {args.input} ({calibration.frames_used} frames). World frame: {WORLD_FRAME}."
        f" Metric scale from limb lengths (upper arm, forearm, thigh, shank) of {args.calibration.limb_lengths_mm} mm."
    )
    sizes = {args.subject: [tuple(int(v) for v in size) for size in calibration.image_size]}
    comparison = reference = None
    if args.reference is not None:  # read before anything is written: a bad reference leaves no output
        reference = read_reference(args.reference, args.reference_subject or args.subject, calibration.camera_names)
        R_ref, t_ref = (np.asarray(a, np.float64) for a in (reference.R, reference.t))
        comparison = compare_rigs(calibration.cameras.R, calibration.cameras.t, R_ref, t_ref)
    with atomic_output(args.output) as temporary:
        save_cameras(temporary, {args.subject: (list(calibration.camera_names), calibration.cameras)}, sizes, comment)
    text = report(calibration, comparison, reference)
    with atomic_output(args.output.with_suffix(".md")) as temporary:
        temporary.write_text(text)
    figure = viz.figure_rig(
        camera_centres(calibration.cameras.R, calibration.cameras.t) if comparison is None else comparison.aligned_centres,
        calibration.cameras.R if comparison is None else comparison.aligned_R,
        calibration.camera_names,
        reference=None if reference is None else (camera_centres(R_ref, t_ref), R_ref),
    )
    with atomic_output(args.output.with_suffix(".png")) as temporary:
        viz.save_figure(figure, temporary)
    print(text)
    print(f"wrote {args.output}, {args.output.with_suffix('.md')}, {args.output.with_suffix('.png')}")
    return calibration, comparison


def main(argv: Sequence[str] | None = None) -> tuple[Calibration, RigComparison | None]:
    args = tyro.cli(CalibrateArgs, args=argv, prog="python -m jaxpose.calibrate", description=__doc__.split("\n\n")[0])
    enable_compilation_cache()  # the bundle adjustment's programs from disk on the next run
    try:
        return run(args)
    except ValueError as error:  # CalibrationError and DataFormatError included
        raise SystemExit(f"error: {error}") from None


if __name__ == "__main__":
    main()
