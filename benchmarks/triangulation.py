"""The DLT solvers of `jaxpose.triangulation` compared.

    python -m benchmarks.triangulation [--quick] [--out runs/benchmarks/triangulation.json]

1. Speed of `triangulate(P, points2d, weights, method)` for method svd / eigh / normal at the
   paper's batch (8192 samples x 17 joints = 139,264 systems, C = 4 views): the forward pass,
   and forward + backward (the gradient with respect to the 2D points).
2. Accuracy under detection noise: exact projections of the synthetic data set's poses (4 rigs)
   plus isotropic Gaussian noise of 0, 2, 5 and 10 px per axis; mean 3D error to the truth (mm).

The geometry's share of the train step (losses and output triangulation, per solver) is measured
by `python -m benchmarks.train_step [--solver svd|eigh|normal]`.

All timings are medians of `--rounds` interleaved calls after warm-up, wall and process CPU time.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import tyro

from benchmarks.train_step import PAPER, environment, medians, timed_rounds
from jaxpose.camera import projection_matrices
from jaxpose.synthetic import SyntheticConfig, generate
from jaxpose.triangulation import triangulate

ROOT = Path(__file__).resolve().parents[1]
METHODS = ("svd", "eigh", "normal")
NOISE_PX = (0.0, 2.0, 5.0, 10.0)


def exact_views(num_samples: int, num_views: int, subjects: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(P [N, C, 3, 4], exact pixels [N, C, J, 2], world truth [N, J, 3]) of noise-free synthetic data."""
    clean = SyntheticConfig(
        num_train_subjects=subjects, num_test_subjects=0, samples_per_subject=num_samples // subjects, num_views=num_views,
        noise_sigma_scale=0.0, outlier_rate=0.0, swap_rate=0.0, missing_rate=0.0,
    )
    data = generate(clean)
    P = np.asarray(projection_matrices(data.rigs))[data.samples.rig_index]
    return P.astype(np.float32), data.samples.keypoints2d, data.samples.target3d


def solver_speed(P: jax.Array, points: jax.Array, rounds: int) -> dict:
    cotangent = jnp.ones(points.shape[:1] + points.shape[2:3] + (3,), jnp.float32)
    programs = {}
    for method in METHODS:
        forward = jax.jit(lambda P, x, method=method: triangulate(P, x, None, method))
        backward = jax.jit(jax.grad(lambda x, P, method=method: jnp.vdot(triangulate(P, x, None, method), cotangent)))
        programs[f"{method}/forward"] = lambda f=forward: f(P, points)
        programs[f"{method}/forward+backward"] = lambda f=backward: f(points, P)
    for run in programs.values():
        jax.block_until_ready(run())
    return medians(timed_rounds(programs, rounds))


def solver_accuracy(P: np.ndarray, pixels: np.ndarray, truth: np.ndarray) -> dict:
    rng = np.random.default_rng(0)
    solve = {method: jax.jit(lambda P, x, method=method: triangulate(P, x, None, method)) for method in METHODS}
    errors = {}
    for sigma in NOISE_PX:
        noisy = jnp.asarray(pixels + rng.normal(0.0, sigma, pixels.shape).astype(np.float32))
        estimates = {method: np.asarray(solve[method](jnp.asarray(P), noisy)) for method in METHODS}
        errors[f"{sigma:g}px"] = {
            **{method: float(np.linalg.norm(estimates[method] - truth, axis=-1).mean()) for method in METHODS},
            **{f"{method}_vs_svd": float(np.linalg.norm(estimates[method] - estimates["svd"], axis=-1).mean()) for method in METHODS[1:]},
        }
    return errors


def markdown(result: dict) -> str:
    lines = ["| method | forward ms | forward+backward ms | " + " | ".join(f"error {k} (mm)" for k in result["accuracy"]) + " |"]
    lines.append("|---|---:|---:|" + "---:|" * len(result["accuracy"]))
    for method in METHODS:
        speed = result["speed"]
        cells = [f"{1e3 * speed[f'{method}/forward']['wall']:.1f}", f"{1e3 * speed[f'{method}/forward+backward']['wall']:.1f}"]
        for noise, errors in result["accuracy"].items():
            versus = f" (vs svd {errors[f'{method}_vs_svd']:.3f})" if method != "svd" else ""
            cells.append(f"{errors[method]:.3f}{versus}")
        lines.append(f"| {method} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


@dataclasses.dataclass(frozen=True)
class Args:
    """The benchmark's flags."""

    quick: bool = False
    """1024 samples instead of the paper's 8192."""
    out: Path = ROOT / "runs" / "benchmarks" / "triangulation.json"
    """JSON results (a markdown table is written beside it)."""
    rounds: int = 7
    """Timed calls of each program after warm-up (the median is reported)."""


def main(argv: Sequence[str] | None = None) -> None:
    args = tyro.cli(Args, args=argv, description=__doc__, prog="python -m benchmarks.triangulation")
    start = time.perf_counter()
    num_samples = 1024 if args.quick else PAPER[0]
    P, pixels, truth = exact_views(num_samples, PAPER[1])
    result = {
        "systems": int(np.prod(pixels.shape[:1] + pixels.shape[2:3])),
        "views": PAPER[1],
        "speed": solver_speed(jnp.asarray(P), jnp.asarray(pixels), args.rounds),
        "accuracy": solver_accuracy(P, pixels, truth),
    }
    result["environment"] = environment()
    result["total_s"] = time.perf_counter() - start
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1))
    table = markdown(result)
    args.out.with_suffix(".md").write_text(table + "\n")
    print(f"{table}\n\nwritten to {args.out} ({result['total_s']:.0f} s)")


if __name__ == "__main__":
    main()
