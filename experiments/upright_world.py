"""The metric upright world (`jaxpose.calibration.world`) measured on rigs recovered with no calibration.

    python -m experiments.upright_world --source example     # the example project's rig, seeds 0-2
    python -m experiments.upright_world --source synthetic   # synthetic subjects S1-S3, each its own rig

Each rig is recovered by `jaxpose.calibration.calibrate` from the detections alone (intrinsics
unknown), its detections triangulated through it (robust IRLS), and the world found from those 3D
poses: once with the rig's own (limb prior) scale and once with the subject's height given.  The
truth: the simulator's world (z up, floor z = 0, the lower ankle 80 mm above it), brought into the
recovered rig's frame by the similarity that best maps the triangulated joints onto the true ones
(least squares over every joint).  Columns: the angle between the found and the true up, the largest
height of the true floor in the found world over the 4 m x 4 m capture area, the scale error.

`synthetic`: the first `subjects` subjects of the default synthetic data set (each its own jittered
rig, H36M_17 joints, all eight motion families in turn), 1,500 instants each, K withheld.  `example`: the example
project's simulation (`jaxpose.synthetic.project`: COCO-17 keypoints, 1920x1080 lenses with mild
distortion, three recordings: walking, reaching, crouching) without its passer-by and with every
camera in sync (what a reader of the project gives once it picks the subject and syncs the
cameras), no calibration file, K withheld; the world from all three recordings together.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import numpy as np
import tyro

from jaxpose.calibration import CalibrationConfig, RigDetections, calibrate, from_dataset
from jaxpose.calibration.world import ANKLE_HEIGHT_FRACTION, SHOULDER_HEIGHT_FRACTION, points_to_world, world_frame
from jaxpose.camera import projection_matrices, undistort_points
from jaxpose.rotations import similarity
from jaxpose.robust import irls_triangulate
from jaxpose.skeleton import COCO_17, Skeleton
from jaxpose.synthetic import ANGLE_NAMES, SyntheticConfig, forward_kinematics, generate, keypoints3d, sample_bone_lengths
from jaxpose.synthetic.body import JOINT_INDEX
from jaxpose.synthetic.capture import ExampleProjectConfig, ExampleStream, detect, field_radius2, rig_calibration
from jaxpose.synthetic.config import Stream, stream_rng
from jaxpose.synthetic.motion import sample_motion

FLOOR_GRID = np.stack(np.meshgrid(np.linspace(-2000, 2000, 9), np.linspace(-2000, 2000, 9), [0.0]), -1).reshape(-1, 3)


@dataclasses.dataclass(frozen=True)
class Args:
    """Recover rigs with no calibration, find the upright world from the person, compare with the truth."""

    source: Literal["synthetic", "example"] = "synthetic"
    seeds: tuple[int, ...] = (0, 1, 2)
    """Example project seeds (one rig each); ignored for `synthetic`."""
    subjects: int = 3
    """Synthetic subjects (one rig each); ignored for `example`."""
    max_frames: int = 600
    """Frames the calibration uses."""


def subject_height(bones: np.ndarray) -> float:
    """The height `jaxpose.calibration.world`'s table gives a simulated body: its rest pose's shoulders
    stand (0.818 - 0.039) of it above its ankles."""
    rest = forward_kinematics(np.zeros((1, len(ANGLE_NAMES))), np.zeros(1), bones)[0]
    shoulders = rest[[JOINT_INDEX["LShoulder"], JOINT_INDEX["RShoulder"]], 2].mean()
    ankles = rest[[JOINT_INDEX["LFoot"], JOINT_INDEX["RFoot"]], 2].mean()
    return (shoulders - ankles) / (SHOULDER_HEIGHT_FRACTION - ANKLE_HEIGHT_FRACTION)


def measure(detections: RigDetections, truth: np.ndarray, skeleton: Skeleton, height: float, max_frames: int) -> dict:
    """Calibrate, triangulate, find the world (rig scale; height given), compare with the true joints [N, J, 3]."""
    calibration = calibrate(detections, CalibrationConfig(max_frames=max_frames))
    cameras = calibration.cameras
    pixels = np.asarray(undistort_points(cameras, detections.keypoints.astype(np.float32)))
    confidence = np.where(detections.confidence >= 0.3, detections.confidence, 0.0).astype(np.float32)
    P = np.asarray(projection_matrices(cameras), np.float32)
    points, weight = (np.asarray(array, np.float64) for array in irls_triangulate(P, pixels, confidence))
    valid = weight > 0
    s, Q, u = similarity(points[valid], truth[valid])  # rig -> true world
    row = {"reprojection_px": float(np.median(calibration.reprojection_median_px))}
    for name, frame in (("rig scale", world_frame(points, valid, skeleton)), ("height given", world_frame(points, valid, skeleton, height_mm=height))):
        up = np.degrees(np.arccos(np.clip(frame.R[1] @ Q[2], -1.0, 1.0)))  # true up in rig axes: Q^T e_z
        floor = points_to_world(frame, (FLOOR_GRID - u) @ Q / s)[:, 1]
        row[name] = (float(up), float(np.abs(floor).max()), frame.scale / s - 1.0, frame.up_source)
    return row


def synthetic_rows(subjects: int, max_frames: int) -> list[tuple[str, dict]]:
    config = SyntheticConfig(num_train_subjects=subjects, num_test_subjects=0, samples_per_subject=1500)
    dataset = generate(config)
    names = tuple(f"camera{c}" for c in range(dataset.num_views))
    rows = []
    for index, subject in enumerate(dict.fromkeys(dataset.samples.labels["subject"].tolist())):
        of_subject = dataset.where(subject=[subject])
        detections = from_dataset(of_subject, subject, names, np.tile(config.image_size, (dataset.num_views, 1))).without_intrinsics()
        bones = sample_bone_lengths(stream_rng(config, Stream.BODY, index))
        rows.append((subject, measure(detections, of_subject.samples.target3d.astype(np.float64), dataset.skeleton, subject_height(bones), max_frames)))
    return rows


def example_rows(seeds: tuple[int, ...], max_frames: int) -> list[tuple[str, dict]]:
    rows = []
    for seed in seeds:
        config = ExampleProjectConfig(seed=seed, desync_camera=-1, second_person_rate=0.0)
        rig = rig_calibration(config)
        bones = sample_bone_lengths(stream_rng(config.synthetic_config(), Stream.BODY, 0))
        radius2 = field_radius2(rig.cameras, config.image_size)
        keypoints, scores, truth = [], [], []
        for r in range(config.recordings):
            motion = sample_motion(config.rng(ExampleStream.MOTION, r), config.motion(r), bones, config.frames_per_recording, config.synthetic_config())
            points = keypoints3d(motion.poses, bones, config.layout)
            person = detect(config, rig, radius2, points, (r, 0))
            keypoints.append(person.keypoints)
            scores.append(person.scores)
            truth.append(points)
        detections = RigDetections(
            keypoints=np.concatenate(keypoints).astype(np.float32), confidence=np.concatenate(scores).astype(np.float32),
            camera_names=config.camera_names, image_size=rig.image_size, skeleton=COCO_17, source=f"example project seed {seed}",
        )  # fmt: skip
        rows.append((f"seed {seed}", measure(detections, np.concatenate(truth), COCO_17, subject_height(bones), max_frames)))
    return rows


def main(argv=None) -> list[tuple[str, dict]]:
    args = tyro.cli(Args, args=argv, prog="python -m experiments.upright_world", description=__doc__.split("\n\n")[0])
    rows = synthetic_rows(args.subjects, args.max_frames) if args.source == "synthetic" else example_rows(args.seeds, args.max_frames)
    print(
        "| rig | re-projection median (px) | up error (deg), rig scale | floor error, max (mm) | scale error |"
        " up error (deg), height given | floor error, max (mm) | scale error | up from |\n|---|---|---|---|---|---|---|---|---|"
    )
    for name, row in rows:
        a, b = row["rig scale"], row["height given"]
        print(
            f"| {name} | {row['reprojection_px']:.1f} | {a[0]:.2f} | {a[1]:.0f} | {a[2]:+.1%} | {b[0]:.2f} | {b[1]:.0f} |"
            f" {b[2]:+.1%} | {b[3]} |"
        )
    return rows


if __name__ == "__main__":
    main()
