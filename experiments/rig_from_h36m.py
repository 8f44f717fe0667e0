"""Write a Human3.6M subject as a rig project, to measure `experiments.rig` where the truth is known.

    python -m experiments.rig_from_h36m --data-dir ../shared/data/h36m_s1 --output runs/h36m_s1_rig
    python -m experiments.rig --data.root runs/h36m_s1_rig --data.validation-recordings ... (printed)

One recording per sequence (e.g. "Walking 1"), every frame at 50 fps:
- `detections.npz`: the 2D of the four cameras (`--detections`: sh, the Stacked Hourglass files, or
  gt, the ground truth projected), as detected (distorted), with the skeleton name and image sizes;
- `ground_truth.npz`: the 3D ground truth of the same joints (world mm, frames, joint names);
- `calibration.toml` at the project root (omitted with `--no-calibration`): cameras.h5 of the
  subject in the Anipose / Pose2Sim layout in metres.  Human3.6M's distortion has no exact OpenCV
  equivalent; the closest OpenCV coefficients are written and their largest pixel difference is
  printed (`jaxpose.formats.h36m_cameras.opencv_from_h36m_distortion`).

The development protocol of `experiments.h36m --preset dev` (the first trial of each action trains,
the other tests, every 5th frame) is then `--data.validation-recordings <the other trials>
--data.train-stride 5 --data.validation-stride 5`, printed at the end.  `--shift CAMERA=N` moves
one camera's frames by N (its frame f then shows the others' frame f + N), to test
`--data.sync auto`.

`--moved PATTERN ...` writes the recordings whose names match (shell patterns, e.g. 'Walk*') as a
second session, filmed through the subject's rig with every camera moved by 100-500 mm and turned by
1-3 degrees (`jaxpose.synthetic.sessions.moved_rig`, seeded by `--moved-seed`): their detections are
the ground truth projected through the moved cameras (Human3.6M's lens kept) plus the subject's own
Stacked Hourglass residuals (its detection minus the ground truth projected through the true camera);
their ground truth stays in the motion capture's world.  The moved rig is written to `moved_rig.npz`
(camera_names, K, R, t, dist, distortion_model "h36m", the moved recordings), which no loader reads as a
calibration, and, without --no-calibration, as each moved recording's own calibration.toml.
"""

from __future__ import annotations

import dataclasses
import fnmatch
import pathlib
import re
from collections.abc import Sequence

import numpy as np
import tyro

from experiments.h36m import first_trials
from jaxpose.formats.anipose_toml import write_anipose_toml
from jaxpose.formats.h36m_cameras import H36M_IMAGE_SIZES, opencv_rig_from_h36m
from jaxpose.formats.calibration_files import read_rig_calibration
from jaxpose.datasets.h36m import CAMERA_NAMES, load_h36m
from jaxpose.camera import Cameras, project
from jaxpose.formats.outputs import atomic_output
from jaxpose.formats.rig_folder import CALIBRATION_TOML, DETECTIONS_NPZ, GROUND_TRUTH_NPZ
from jaxpose.synthetic.sessions import moved_rig

MOVED_RIG_NPZ = "moved_rig.npz"


@dataclasses.dataclass(frozen=True)
class Args:
    """Write a Human3.6M subject as a rig project (see the module docstring)."""

    data_dir: pathlib.Path
    """The Human3.6M folder (h36m.zip tree with cameras.h5)."""
    output: pathlib.Path
    """The project folder to write."""
    subject: str = "S1"
    """The subject written."""
    detections: str = "sh"
    """2D source: sh (Stacked Hourglass, 16 joints) or gt (the ground truth projected, 17 joints)."""
    calibration: bool = True
    """Write calibration.toml (--no-calibration: the rig must then be recovered from the recordings)."""
    shift: tuple[str, ...] = ()
    """CAMERA=N: that camera's frame f shows the other cameras' frame f + N (frames without a
    counterpart are dropped)."""
    intrinsics: bool = False
    """Write each camera's K and lens (Human3.6M's distortion as OpenCV's) into detections.npz: intrinsics
    known (a per-camera checkerboard), the rig itself still recovered where there is no calibration.toml."""
    moved: tuple[str, ...] = ()
    """Shell patterns of the recordings filmed through a moved rig (a second session; see the module docstring)."""
    moved_seed: int = 0
    """The seed of the moved rig's shifts and turns."""
    overwrite: bool = False
    """Write into an --output folder that already holds a project (its calibration.toml and the
    recordings' detections.npz / ground_truth.npz are replaced); without it such a folder stops the
    command before any work.  --data-dir is never written."""


def check_output(args: Args) -> None:
    """Refuse, before any work, an --output that is a file, is the input, or holds a project (unless --overwrite)."""
    if args.output.exists() and not args.output.is_dir():
        raise SystemExit(f"--output {args.output}: is a file; give a folder for the project")
    if args.output.resolve() == args.data_dir.resolve():
        raise SystemExit(f"--output {args.output}: is this command's input --data-dir; choose another folder")
    if args.output.is_dir() and not args.overwrite:
        existing = sorted(
            path for name in (CALIBRATION_TOML, DETECTIONS_NPZ, GROUND_TRUTH_NPZ) for path in args.output.rglob(name)
        )
        if existing:
            raise SystemExit(f"--output {args.output}: holds a project already ({existing[0]}, ...); pass --overwrite to replace its files")


def write_project(args: Args) -> list[str]:
    """Write the project; returns the recordings of the development protocol's test half."""
    check_output(args)
    dataset = load_h36m(args.data_dir, detections=args.detections, subjects=(args.subject,), train_stride=1, test_stride=1)
    shifts = {}
    for value in args.shift:
        match = re.fullmatch(r"(\w+)=([+-]?\d+)", value)
        if match is None or match[1] not in CAMERA_NAMES:
            raise SystemExit(f"--shift {value!r}: expected CAMERA=N with CAMERA one of {CAMERA_NAMES}")
        shifts[match[1]] = int(match[2])
    sequences = dataset.samples.labels["sequence"]
    moved = sorted(name for name in set(sequences.tolist()) if any(fnmatch.fnmatchcase(name, pattern) for pattern in args.moved))
    if args.moved and not moved:
        raise SystemExit(f"--moved {list(args.moved)}: matches no recording (have {sorted(set(sequences.tolist()))[:6]} ...)")
    args.output.mkdir(parents=True, exist_ok=True)
    true_rig = read_rig_calibration(args.data_dir / "cameras.h5", subject=args.subject).select(CAMERA_NAMES, "Human3.6M cameras")
    true_rig = dataclasses.replace(true_rig, image_size=np.array([H36M_IMAGE_SIZES[name] for name in CAMERA_NAMES]))
    moved_cameras = None
    if moved:
        moved_cameras = _moved(true_rig.cameras, args.moved_seed)
        with atomic_output(args.output / MOVED_RIG_NPZ) as temporary:
            np.savez(
                temporary, camera_names=np.array(CAMERA_NAMES), K=moved_cameras.K, R=moved_cameras.R, t=moved_cameras.t,
                dist=moved_cameras.dist, distortion_model=np.array(moved_cameras.distortion_model), recordings=np.array(moved),
            )  # fmt: skip
    if args.calibration:
        rig, error_px = opencv_rig_from_h36m(true_rig)
        with atomic_output(args.output / CALIBRATION_TOML) as temporary:
            write_anipose_toml(temporary, rig, unit="m")
        print(f"calibration.toml: Human3.6M's distortion as OpenCV's, largest difference {error_px:.3f} px")
    train = first_trials(dataset.samples.labels["subject"], dataset.samples.labels["action"], sequences)
    image_size = np.array([H36M_IMAGE_SIZES[name] for name in CAMERA_NAMES])
    lenses = {}
    if args.intrinsics:
        lens = opencv_rig_from_h36m(true_rig)[0].cameras
        lenses = {"K": np.asarray(lens.K, np.float64), "dist": np.asarray(lens.dist, np.float64), "distortion_model": np.array("opencv")}
    for sequence in sorted(set(sequences.tolist())):
        rows = np.flatnonzero(sequences == sequence)
        frames = dataset.samples.labels["frame"][rows].astype(np.int64)
        keypoints = dataset.samples.keypoints2d[rows].copy()
        confidence = dataset.samples.confidence[rows].copy()
        if sequence in moved:
            keypoints = _through_moved_rig(keypoints, dataset.samples.target3d[rows], true_rig.cameras, moved_cameras)
        for camera, shift in shifts.items():
            c = CAMERA_NAMES.index(camera)
            # Camera c's frame f shows the instant of the others' frame f + shift.
            source = np.clip(np.arange(len(rows)) + shift, 0, len(rows) - 1)
            keypoints[:, c] = keypoints[source, c]
            outside = (np.arange(len(rows)) + shift < 0) | (np.arange(len(rows)) + shift >= len(rows))
            confidence[outside, c] = 0.0
        folder = args.output / sequence
        folder.mkdir(exist_ok=True)
        if sequence in moved and args.calibration:
            moved_calibration, _ = opencv_rig_from_h36m(dataclasses.replace(true_rig, cameras=moved_cameras))
            with atomic_output(folder / CALIBRATION_TOML) as temporary:
                write_anipose_toml(temporary, moved_calibration, unit="m")
        with atomic_output(folder / DETECTIONS_NPZ) as temporary:
            np.savez(
                temporary,
                keypoints=keypoints, confidence=confidence, camera_names=np.array(CAMERA_NAMES), image_size=image_size,
                skeleton=np.array(dataset.skeleton.name), frames=frames, **lenses,
            )  # fmt: skip
        with atomic_output(folder / GROUND_TRUTH_NPZ) as temporary:
            np.savez(
                temporary,
                points3d=dataset.samples.target3d[rows], frames=frames, joint_names=np.array(dataset.skeleton.joint_names),
            )  # fmt: skip
    return sorted(set(sequences[~train].tolist()))


def _moved(cameras: Cameras, seed: int) -> Cameras:
    """`cameras` with each camera moved by 100-500 mm and turned by 1-3 degrees, their lenses kept."""
    moved = moved_rig(np.random.default_rng([seed, 43]), cameras)
    return moved.replace(
        K=np.asarray(cameras.K, np.float64), R=np.asarray(moved.R, np.float64), t=np.asarray(moved.t, np.float64),
        dist=None if cameras.dist is None else np.asarray(cameras.dist, np.float64), distortion_model=cameras.distortion_model,
    )  # fmt: skip


def _through_moved_rig(keypoints: np.ndarray, points3d: np.ndarray, true: Cameras, moved: Cameras) -> np.ndarray:
    """The detections `keypoints` [N, C, J, 2] of the mocap `points3d` [N, J, 3] as the moved cameras would
    have made them: the mocap projected through the moved cameras plus the detector's own residual (its
    detection minus the mocap projected through the true camera)."""
    through_true = np.asarray(project(true, points3d[:, None]), np.float64)
    through_moved = np.asarray(project(moved, points3d[:, None]), np.float64)
    return (through_moved + keypoints - through_true).astype(keypoints.dtype)


def main(argv: Sequence[str] | None = None) -> list[str]:
    args = tyro.cli(Args, args=argv, prog="python -m experiments.rig_from_h36m", description=__doc__.split("\n\n")[0])
    held_out = write_project(args)
    quoted = " ".join(f"'{name}'" for name in held_out)
    print(
        f"wrote {args.output}. The development protocol:\n  python -m experiments.rig --data.root {args.output}"
        f" --data.train-stride 5 --data.validation-stride 5 --data.validation-recordings {quoted}"
    )
    return held_out


if __name__ == "__main__":
    main()
