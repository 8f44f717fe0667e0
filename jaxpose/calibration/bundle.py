"""Bundle adjustment of a rig over the person's joints, in JAX.

The unknowns are every camera's pose (and, when the intrinsics are unknown, its focal length) and
every joint of every frame.  The joints are not separate parameters: given the cameras, each one
is triangulated in closed form, so the solver only sees the ~7 parameters per camera while every
residual still depends on the joints it implies ("variable projection").  That keeps the
Levenberg-Marquardt system tiny (a dense [residuals, ~7C] Jacobian) however many frames are used.
The triangulation is the weighted linear one of `jaxpose.triangulation`, re-weighted twice by each
view's depth, so that its point-to-plane distances become angular (pixel) errors and the point is
close to the reprojection-error optimum.

A detector's outliers (left/right swaps, a limb mistaken for another) are handled by iteratively
re-weighted least squares: each round fixes Cauchy weights from the current residuals, both in the
triangulation and in the residuals, and solves to convergence (optimistix's Levenberg-Marquardt).
Rotations are updated on SO(3) with jaxlie.  Gauge: view 0 stays at the origin with identity
rotation, and one residual holds view 1's distance from it; the metric scale is set afterwards
from the body (`jaxpose.calibration.scale`).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import optimistix as optx

from jaxpose.calibration.initial import CalibrationError
from jaxpose.camera import project_with_matrices
from jaxpose.triangulation import triangulate

# Depth re-weightings of the triangulation: one already brings the point within a fraction of a
# pixel of the optimum at these baselines; two make it indistinguishable.
REWEIGHTINGS = 2
# Cauchy scale as a multiple of the median residual: inliers keep ~full weight, a swapped joint
# (tens of pixels off) next to none.
CAUCHY_SCALE_PER_MEDIAN = 3.0
EARLY_ROUND_STEPS = 10
GAUGE_WEIGHT = 1e4  # pixels per rig unit of the scale-gauge residual
# Tolerances on the parameters (radians, rig units ~ the first baseline, log focal): 1e-6 rad is
# 0.00006 degrees, far below what the detections determine.
SOLVER = optx.LevenbergMarquardt(rtol=1e-5, atol=1e-6)


@dataclasses.dataclass(frozen=True)
class BundleResult:
    """The adjusted rig, in the initial rig's units (view 0 at the origin)."""

    R: np.ndarray
    """f64[C, 3, 3] world-to-camera rotations."""
    t: np.ndarray
    """f64[C, 3] translations."""
    K: np.ndarray
    """f64[C, 3, 3] intrinsics (the given ones, or with the estimated focal lengths)."""
    points: np.ndarray
    """f64[F, J, 3] the joints the final cameras triangulate."""
    error_px: np.ndarray
    """f64[F, C, J] re-projection error of every observation (NaN where not observed)."""
    weights: np.ndarray
    """f64[F, C, J] the final robust weights (0 where not observed)."""


def _cameras(params: dict, R0: jax.Array, t0: jax.Array, K0: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """(P [C, 3, 4], R, K) from the parameters; view 0 is the fixed gauge."""
    update = jaxlie.SO3.exp(params["rotation"]).as_matrix()  # [C-1, 3, 3]
    R = jnp.concatenate([R0[:1], update @ R0[1:]])
    t = jnp.concatenate([t0[:1], params["translation"]])
    K = K0
    if "log_focal" in params:  # unknown intrinsics: one focal factor per camera, principal point kept
        K = K0.at[:, :2, :2].multiply(jnp.exp(params["log_focal"])[:, None, None])
    return K @ jnp.concatenate([R, t[..., None]], axis=-1), R, K


def _triangulate_and_project(P: jax.Array, pixels: jax.Array, weights: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Joints [F, J, 3] from pixels [F, C, J, 2] with weights [F, C, J], and their re-projections [F, C, J, 2]."""
    # Triangulation weights multiply distances, the robust weights squared residuals: hence the root.
    row_weights = jnp.sqrt(weights)
    points = triangulate(P, pixels, row_weights, method="normal")
    for _ in range(REWEIGHTINGS):
        depth = jnp.abs(project_with_matrices(P, points)[..., 2])  # [F, C, J]
        nearest = jnp.max(jnp.where(weights > 0, depth, 0.0), axis=1, keepdims=True)  # keeps weights O(1)
        points = triangulate(P, pixels, row_weights * nearest / jnp.maximum(depth, 1e-6 * nearest + 1e-30), method="normal")
    homogeneous = project_with_matrices(P, points)
    depth = homogeneous[..., 2:3]
    # A joint behind a camera (only possible far from the solution) re-projects far away, not to NaN.
    return points, homogeneous[..., :2] / jnp.where(depth > 1e-9, depth, 1e-9)


def _residuals(params: dict, args: tuple) -> jax.Array:
    R0, t0, K0, pixels, weights = args
    P, _, _ = _cameras(params, R0, t0, K0)
    _, projected = _triangulate_and_project(P, pixels, weights)
    # The scale gauge: nothing in the images fixes it, so one residual holds view 1's distance from
    # view 0 at its start value (a free null direction lets the solver drift and stalls its stopping test).
    gauge = GAUGE_WEIGHT * (jnp.linalg.norm(params["translation"][0]) - jnp.linalg.norm(t0[1]))
    return jnp.concatenate([(jnp.sqrt(weights)[..., None] * (projected - pixels)).reshape(-1), gauge[None]])


def _errors(params: dict, args: tuple) -> tuple[jax.Array, jax.Array]:
    """Joints and the per-observation re-projection error (px) under the given weights."""
    R0, t0, K0, pixels, weights = args
    P, _, _ = _cameras(params, R0, t0, K0)
    points, projected = _triangulate_and_project(P, pixels, weights)
    return points, jnp.linalg.norm(projected - pixels, axis=-1)


def _cauchy_weights(error: jax.Array, observed: jax.Array) -> jax.Array:
    median = jnp.nanmedian(jnp.where(observed, error, jnp.nan))
    scale = CAUCHY_SCALE_PER_MEDIAN * jnp.maximum(median, 1e-6)
    return jnp.where(observed, 1.0 / (1.0 + (error / scale) ** 2), 0.0)


@functools.partial(jax.jit, static_argnames="max_steps")
def _reweight_and_solve(params, R0, t0, K0, pixels, observed, max_steps: int):
    """One robust round: Cauchy weights from the current residuals, then Levenberg-Marquardt under them."""
    _, error = _errors(params, (R0, t0, K0, pixels, observed.astype(pixels.dtype)))
    weights = _cauchy_weights(error, observed)
    solution = optx.least_squares(
        _residuals, SOLVER, params, args=(R0, t0, K0, pixels, weights), max_steps=max_steps, throw=False
    )
    return solution.value, weights


@jax.jit
def _final(params, R0, t0, K0, pixels, weights):
    points, error = _errors(params, (R0, t0, K0, pixels, weights))
    _, R, K = _cameras(params, R0, t0, K0)
    return R, jnp.concatenate([t0[:1], params["translation"]]), K, points, error


def bundle_adjust(
    R: np.ndarray,
    t: np.ndarray,
    K: np.ndarray,
    pixels: np.ndarray,
    observed: np.ndarray,
    estimate_focal: bool,
    rounds: int = 4,
    max_steps: int = 100,
) -> BundleResult:
    """Refine a rig (R [C, 3, 3], t [C, 3], view 0 = identity, origin) on undistorted pixels
    [F, C, J, 2] observed where `observed` [F, C, J]; K [C, 3, 3] stays fixed unless `estimate_focal`
    (then each camera's fx and fy are scaled by one factor; the principal point stays)."""
    C = R.shape[0]
    # float64: the loss sums ~1e5 squared pixel residuals, whose float32 sum cannot resolve the
    # sub-pixel improvements that separate a 0.1 degree rotation error from a 1 degree one.
    with jax.enable_x64(True):
        params = {"rotation": jnp.zeros((C - 1, 3), jnp.float64), "translation": jnp.asarray(t[1:], jnp.float64)}
        if estimate_focal:
            params["log_focal"] = jnp.zeros(C, jnp.float64)
        R0, t0, K0, pixels64 = (jnp.asarray(a, jnp.float64) for a in (R, t, K, pixels))
        observed = jnp.asarray(observed)
        for round_index in range(rounds):
            # The early rounds only need to bring the outliers' weights down; the last one converges.
            limit = max_steps if round_index == rounds - 1 else EARLY_ROUND_STEPS
            params, weights = _reweight_and_solve(params, R0, t0, K0, pixels64, observed, limit)
        R_out, t_out, K_out, points, error = _final(params, R0, t0, K0, pixels64, weights)
    if not all(np.all(np.isfinite(np.asarray(a))) for a in (R_out, t_out, K_out)):
        raise CalibrationError("the bundle adjustment diverged (non-finite cameras); check the detections' views and names")
    error = np.where(observed, np.asarray(error, np.float64), np.nan)
    return BundleResult(
        R=np.asarray(R_out, np.float64), t=np.asarray(t_out, np.float64), K=np.asarray(K_out, np.float64),
        points=np.asarray(points, np.float64), error_px=error, weights=np.asarray(weights, np.float64),
    )  # fmt: skip
