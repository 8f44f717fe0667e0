"""The trajectory's motion prior on real motion: CMU motion capture (BVH) seen by a simulated rig, per kind of
motion, the default (the prior estimated per recording and joint) against each instant alone (--no-smoothing)
and fixed process noises.

    python -m experiments.motion_prior ../shared/data/cmu_mocap/05/*.bvh ../shared/data/cmu_mocap/06/*.bvh --fps 30

Per file: its joints placed on Human3.6M's 17 (`jaxpose.formats.bvh`, `jaxpose.synthetic.mocap`), taken every
120/fps-th frame (at most --max-seconds), seen by `jaxpose.synthetic.rig.make_rig`'s cameras (--views) and the simulated
detector (`simulate_detector`: per-joint noise of 3-8 px, 2% outliers, 1% left/right swaps), each view's lift
the true root-relative pose in the camera's axes plus --lift-noise-mm per axis (a lifter's error), fused per
instant (`fuse`), then solved by `solve_trajectory` (each --configs entry).  World MPJPE (mm) and the
acceleration error (mm/frame^2) against the mocap, the mean over --seeds rigs and detector draws (the spread
is their standard deviation).  The kind of a file is its name's subject and number (`KINDS`).

`benchmarks.motion` scores the default against the peers through a trained lifter; this one needs none (the
lifts simulated), to study the trajectory's settings quickly.
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import numpy as np

from jaxpose.camera import Cameras
from jaxpose.formats.bvh import read_bvh
from jaxpose.reconstruction.fusion import FusionConfig, fuse
from jaxpose.reconstruction.motion_quality import acceleration_error
from jaxpose.reconstruction.trajectory import TrajectoryConfig, solve_trajectory
from jaxpose.skeleton import H36M_17
from jaxpose.synthetic.config import SyntheticConfig
from jaxpose.synthetic.detector import simulate_detector
from jaxpose.synthetic.mocap import mocap_keypoints
from jaxpose.synthetic.rig import make_rig, project_points

KINDS = {"02_01": "walk", "02_02": "walk", "02_03": "jog", "05": "dance", "06": "basketball", "02": "subject 02, other"}
CONFIGS = {
    "default": TrajectoryConfig(),
    "3000": TrajectoryConfig(acceleration_mm_s2=3000.0),
    "gaussian": TrajectoryConfig(acceleration_dof=float("inf")),
    "dof2": TrajectoryConfig(acceleration_dof=2.0),
    "dof8": TrajectoryConfig(acceleration_dof=8.0),
    "no-limbs": TrajectoryConfig(limb_sigma_mm=1e6),
    "3000-no-limbs": TrajectoryConfig(acceleration_mm_s2=3000.0, limb_sigma_mm=1e6),
}


def cmu_motion(path: pathlib.Path, fps: float, seconds: float) -> np.ndarray:
    """f64[F, 17, 3] H36M_17 keypoints of a CMU take (`jaxpose.synthetic.mocap`), world mm, z up, every
    120/fps-th frame, at most `seconds`."""
    bvh = read_bvh(path)
    step = 1.0 / (bvh.frame_time * fps)
    if abs(step - round(step)) > 1e-3:  # a frame time written with 7 digits
        raise ValueError(f"{path}: {1 / bvh.frame_time:g} fps is not a multiple of --fps {fps:g}")
    return mocap_keypoints(bvh, "h36m17")[:: int(round(step))][: int(seconds * fps)]


def seen(truth: np.ndarray, seed: int, views: int, lift_noise_mm: float):
    """The per-instant fusion of the motion seen by a simulated rig and detector (module docstring)."""
    rng = np.random.default_rng(seed)
    config = SyntheticConfig(num_views=views)
    rig = make_rig(rng, config)
    pixels, _ = project_points(rig, truth)
    detections = simulate_detector(rng, pixels, config)
    R, t = np.asarray(rig.R, np.float64), np.asarray(rig.t, np.float64)
    in_camera = np.einsum("cab,njb->ncja", R, truth) + t[None, :, None]
    lifted = in_camera - in_camera[..., :1, :] + rng.normal(0.0, lift_noise_mm, in_camera.shape)
    lifted[..., 0, :] = 0.0
    lifted = np.where((detections.confidence > 0).any(-1)[..., None, None], lifted, np.nan)
    cameras = Cameras(K=np.asarray(rig.K, np.float64), R=R, t=t)
    return fuse(cameras, detections.keypoints2d.astype(np.float64), detections.confidence.astype(np.float64), lifted, FusionConfig())


def kind(path: pathlib.Path) -> str:
    return KINDS.get(path.stem, KINDS.get(path.stem.split("_")[0], "other"))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="+", type=pathlib.Path)
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--views", type=int, default=4)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--max-seconds", type=float, default=10.0)
    parser.add_argument("--lift-noise-mm", type=float, default=40.0)
    parser.add_argument("--configs", default="default,3000", help=f"comma-separated, of {', '.join(CONFIGS)}")
    args = parser.parse_args(argv)
    methods = ["no-smoothing"] + args.configs.split(",")
    results: dict[str, dict[str, list]] = {}  # kind -> method -> [(seed, mpjpe, summed accel error, cells)]
    for path in args.files:
        truth = cmu_motion(path, args.fps, args.max_seconds)
        for seed in range(args.seeds):
            fusion = seen(truth, seed, args.views, args.lift_noise_mm)
            tracks = {"no-smoothing": fusion.points}
            for name in methods[1:]:
                tracks[name] = solve_trajectory(fusion.points, fusion.covariance, fusion.provenance, H36M_17.bones, args.fps, CONFIGS[name]).points
            for name, points in tracks.items():
                errors = np.linalg.norm(points - truth, axis=-1)
                results.setdefault(kind(path), {}).setdefault(name, []).append((seed, errors.sum(), errors.size, *acceleration_error(points, truth)))
        print(f"{path.name}: {len(truth)} frames", file=sys.stderr)
    print(f"| kind of motion ({args.fps:g} fps, {args.views} cameras) | " + " | ".join(methods) + " |")
    print("|---" * (len(methods) + 1) + "|")
    for name, rows in results.items():
        cells = []
        for method in methods:
            table = np.array(rows[method])
            per_seed = [table[table[:, 0] == s] for s in range(args.seeds)]
            mpjpe = np.array([part[:, 1].sum() / part[:, 2].sum() for part in per_seed])
            acceleration = np.array([part[:, 3].sum() / part[:, 4].sum() for part in per_seed])
            cells.append(f"{mpjpe.mean():.1f} ± {mpjpe.std():.1f} ({acceleration.mean():.1f})")
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
