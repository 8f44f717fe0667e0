"""The whole lens recovered from the person: wide-angle synthetic rigs with unknown intrinsics.

    python -m experiments.lens_study                         # 20 rigs x 2 seeds (docs/calibration.md)
    python -m experiments.lens_study --rigs 2 --seeds 0      # a quick look

Each rig is the simulated room (`jaxpose.synthetic.make_rig`, four cameras 4-6 m from the centre)
with wide-angle lenses (`jaxpose.synthetic.lenses`: 1920 x 1080 images, focal length 700-1,200 px,
k1 in [-0.35, 0] and k2 in [0, 0.1] with the distortion monotonic inside the image, principal point
up to 40 px off centre) seeing one synthetic subject through the default detector (noise 3-8 px,
outliers, swaps, missing joints; joints outside the image missing).  `jaxpose.calibration.calibrate`
gets the detections and the image sizes only.  Per rig, against the truth:

- recovered: no refusal and every camera's rotation within 1 degree after a similarity alignment;
- focal error (%), principal point error (px): the worst camera's;
- distortion p95 (px): the 95th percentile over every detected keypoint of the error of the
  recovered lens' distortion displacement (a keypoint's distance from where the lens' pinhole would
  put it), beside the same with no distortion assumed (k = 0: the displacement itself);
- MPJPE (mm): every detected joint triangulated through the recovered rig and through the true rig,
  each brought onto the ground truth by one similarity alignment;
- within 2 sigma: the share of the free intrinsics (focal, cx, cy, k1, k2 of every camera) whose
  truth lies within 2 stated sigma of the estimate.
"""

from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np
import tyro

from jaxpose.calibration import CalibrationConfig, CalibrationError, LensConfig, RigDetections, calibrate, compare_rigs
from jaxpose.camera import Cameras, undistort_points
from jaxpose.metrics import procrustes_align
from jaxpose.skeleton import H36M_17
from jaxpose.synthetic import SyntheticConfig, make_rig, simulate_subject
from jaxpose.synthetic.config import Stream, stream_rng
from jaxpose.synthetic.lenses import WideAngleLenses, detect_through_lenses, wide_angle_lenses
from jaxpose.triangulation import triangulate_cameras

IMAGE_SIZE = (1920, 1080)
LENS_STREAM = 20  # a stream number of its own, after `jaxpose.synthetic.config.Stream`'s
STUDIED = 5  # focal, cx, cy, k1, k2: the intrinsics the study checks (p1, p2 stay off)


@dataclasses.dataclass(frozen=True)
class Args:
    """Recover wide-angle synthetic rigs, lenses included, from the person alone and compare with the truth."""

    rigs: int = 20
    """Rigs per seed."""
    seeds: tuple[int, ...] = (0, 1)
    """Seeds: each draws its own rooms, lenses, subjects and detector noise."""
    frames: int = 1500
    """Instants simulated per rig (the calibration uses at most `calibration.max_frames` of them)."""
    lenses: WideAngleLenses = WideAngleLenses()
    """The lenses drawn."""
    calibration: CalibrationConfig = CalibrationConfig(lens=LensConfig(estimate_principal_point=True, estimate_distortion=True))
    """How the rigs are recovered (by default the whole lens: focal length, principal point, k1, k2)."""


@dataclasses.dataclass(frozen=True)
class Case:
    """One simulated rig and what it saw."""

    rig: Cameras  # numpy, with the true lenses
    detections: RigDetections  # no intrinsics
    poses: np.ndarray  # f64[N, J, 3] ground truth, mm


def make_case(seed: int, index: int, frames: int, lenses: WideAngleLenses = WideAngleLenses()) -> Case:
    """Rig `index` of `seed`: the room, its wide-angle lenses, one subject's motion and detections."""
    config = SyntheticConfig(
        num_train_subjects=1, num_test_subjects=0, samples_per_subject=frames, image_size=IMAGE_SIZE, seed=seed
    )
    room = make_rig(stream_rng(config, Stream.ROOM, index), config)
    K, dist = wide_angle_lenses(stream_rng(config, LENS_STREAM, index), config.num_views, IMAGE_SIZE, lenses)
    rig = Cameras(K=K, R=np.asarray(room.R, np.float64), t=np.asarray(room.t, np.float64), dist=dist)
    poses = simulate_subject(config, index).poses.astype(np.float64)
    seen, _ = detect_through_lenses(stream_rng(config, Stream.DETECTOR, index), rig, poses, IMAGE_SIZE, config)
    detections = RigDetections(
        keypoints=seen.keypoints2d, confidence=seen.confidence, camera_names=tuple(f"cam{c}" for c in range(len(K))),
        image_size=np.tile(np.asarray(IMAGE_SIZE), (len(K), 1)), skeleton=H36M_17, source=f"seed {seed} rig {index}",
    )  # fmt: skip
    return Case(rig=rig, detections=detections, poses=poses)


def displacement(cameras: Cameras, pixels: np.ndarray) -> np.ndarray:
    """f64[N, C, J, 2]: each pixel's distortion displacement (itself minus its undistorted position)
    through cameras [C]; zeros without distortion."""
    if cameras.dist is None:
        return np.zeros_like(pixels)
    with jax.enable_x64(True):
        lens = jax.tree.map(lambda field: jnp.asarray(field, jnp.float64), cameras)
        return pixels - np.asarray(undistort_points(lens, jnp.asarray(pixels, jnp.float64), iterations=100))


def world_mpjpe(cameras: Cameras, detections: RigDetections, poses: np.ndarray, min_confidence: float) -> float:
    """MPJPE (mm) of the detections triangulated through `cameras` after one similarity alignment of
    all triangulated joints onto the ground truth."""
    weights = (detections.confidence >= min_confidence).astype(np.float64)
    usable = weights.sum(1) >= 2  # [N, J]
    with jax.enable_x64(True):
        lens = jax.tree.map(lambda field: jnp.asarray(field, jnp.float64), cameras)
        points = np.asarray(triangulate_cameras(lens, jnp.asarray(detections.keypoints, jnp.float64), jnp.asarray(weights)))
        aligned = np.asarray(procrustes_align(jnp.asarray(points[usable]), jnp.asarray(poses[usable])))
    return float(np.linalg.norm(aligned - poses[usable], axis=-1).mean())


def evaluate(case: Case, config: CalibrationConfig) -> dict:
    """One rig's row (see the module docstring)."""
    truth = case.rig
    true_mpjpe = world_mpjpe(truth, case.detections, case.poses, config.min_confidence)
    try:
        calibration = calibrate(case.detections, config)
    except CalibrationError as error:
        return {"recovered": False, "refusal": str(error), "true_mpjpe": true_mpjpe}
    recovered = calibration.cameras
    comparison = compare_rigs(recovered.R, recovered.t, truth.R, truth.t)
    detected = case.detections.confidence > 0  # [N, C, J]
    pixels = np.where(detected[..., None], case.detections.keypoints, np.asarray(truth.K)[None, :, None, :2, 2])
    true_shift = displacement(truth, pixels)[detected]
    shift_error = np.linalg.norm(displacement(recovered, pixels)[detected] - true_shift, axis=-1)
    true_values = np.concatenate([truth.K[:, :1, 0], truth.K[:, :2, 2], truth.dist[:, :2]], axis=1)
    lens = calibration.lens
    free = lens.state[:, :STUDIED] != "held"
    within = np.abs(lens.value[:, :STUDIED] - true_values) <= 2.0 * lens.sigma[:, :STUDIED]
    return {
        "recovered": bool(comparison.rotation_deg.max() < 1.0),
        "rotation_deg": float(comparison.rotation_deg.max()),
        "focal_error": float(np.max(np.abs(recovered.K[:, 0, 0] / truth.K[:, 0, 0] - 1.0))),
        "principal_point_px": float(np.linalg.norm(recovered.K[:, :2, 2] - truth.K[:, :2, 2], axis=-1).max()),
        "distortion_p95_px": float(np.percentile(shift_error, 95)),
        "no_distortion_p95_px": float(np.percentile(np.linalg.norm(true_shift, axis=-1), 95)),
        "mpjpe": world_mpjpe(recovered, case.detections, case.poses, config.min_confidence),
        "true_mpjpe": true_mpjpe,
        "within": int(within[free].sum()),
        "free": int(free.sum()),
        "at_prior": [f"cam{c}.{name}" for c, name in zip(*np.nonzero(lens.state == "prior"))],
        "residual_scale": calibration.residual_scale,
        "seconds": calibration.seconds,
    }


def main(argv=None) -> list[dict]:
    args = tyro.cli(Args, args=argv, prog="python -m experiments.lens_study", description=__doc__.split("\n\n")[0])
    print(
        "| seed | rig | focal (px) | k1 | recovered | rotation (deg) | focal error | principal point (px) |"
        " distortion p95 (px) | k = 0 p95 (px) | MPJPE (mm) | true rig MPJPE (mm) | within 2 sigma | at prior | time (s) |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
        flush=True,
    )
    rows = []
    began = time.perf_counter()
    for seed in args.seeds:
        for index in range(args.rigs):
            case = make_case(seed, index, args.frames, args.lenses)
            row = {"seed": seed, "rig": index} | evaluate(case, args.calibration)
            rows.append(row)
            focal = f"{case.rig.K[:, 0, 0].min():.0f}-{case.rig.K[:, 0, 0].max():.0f}"
            k1 = f"{case.rig.dist[:, 0].min():.2f}..{case.rig.dist[:, 0].max():.2f}"
            if "focal_error" not in row:
                print(f"| {seed} | {index} | {focal} | {k1} | refused: {row['refusal']} |" + " |" * 10, flush=True)
                continue
            print(
                f"| {seed} | {index} | {focal} | {k1} | {'yes' if row['recovered'] else 'no'} | {row['rotation_deg']:.2f} |"
                f" {row['focal_error']:.2%} | {row['principal_point_px']:.1f} | {row['distortion_p95_px']:.2f} |"
                f" {row['no_distortion_p95_px']:.1f} | {row['mpjpe']:.1f} | {row['true_mpjpe']:.1f} |"
                f" {row['within']}/{row['free']} | {', '.join(row['at_prior']) or '-'} | {row['seconds']:.0f} |",
                flush=True,
            )
    print(summary(rows))
    print(f"\n{len(rows)} rigs in {time.perf_counter() - began:.0f} s")
    return rows


def summary(rows: list[dict]) -> str:
    """The targets' table over every rig: worst, 95th percentile and median where they apply."""
    done = [row for row in rows if "focal_error" in row]

    def stats(key: str, scale: float = 1.0, digits: int = 2) -> str:
        values = np.array([row[key] for row in done]) * scale
        return " / ".join(f"{v:.{digits}f}" for v in (np.median(values), np.percentile(values, 95), values.max()))

    ratio = np.array([row["distortion_p95_px"] / row["no_distortion_p95_px"] for row in done])
    gap = np.array([row["mpjpe"] - row["true_mpjpe"] for row in done])
    within = sum(row["within"] for row in done) / max(sum(row["free"] for row in done), 1)
    lines = [
        "",
        "| measure (median / 95th percentile / worst over rigs) | value | target |",
        "|---|---|---|",
        f"| recovered | {sum(row['recovered'] for row in rows)}/{len(rows)} | >= 95% |",
        f"| focal error (%) | {stats('focal_error', 100.0)} | <= 1.5 |",
        f"| principal point error (px) | {stats('principal_point_px', digits=1)} | <= 10 |",
        f"| distortion displacement error, p95 over keypoints (px) | {stats('distortion_p95_px')} | <= 1.5 |",
        f"| the same with k = 0 (px) | {stats('no_distortion_p95_px', digits=1)} | |",
        "| ratio of the two | " + " / ".join(f"{v:.3f}" for v in (np.median(ratio), np.percentile(ratio, 95), ratio.max())) + " | <= 1/3 |",
        "| MPJPE, recovered rig - true rig (mm) | " + " / ".join(f"{v:+.1f}" for v in (np.median(gap), np.percentile(gap, 95), gap.max())) + " | <= 3 |",
        f"| MPJPE through the true rig (mm) | {stats('true_mpjpe', digits=1)} | |",
        f"| truth within 2 sigma (all free intrinsics) | {within:.1%} | ~95% |",
        f"| residual variance factor | {stats('residual_scale')} | ~1 |",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
