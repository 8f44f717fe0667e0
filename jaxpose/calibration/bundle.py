"""Bundle adjustment of a rig over the person's joints, in JAX.

The unknowns are every camera's pose and unknown intrinsics (focal length, principal point, radial
distortion: `jaxpose.calibration.lens`) and every joint of every frame.  The joints are not separate
parameters: given the cameras, each one is triangulated in closed form from the detections
undistorted through the current lenses, so the solver only sees the 6-13 parameters per camera
while every residual, in the detections' own (distorted) pixels, still depends on the joints it
implies ("variable projection").  That keeps the Levenberg-Marquardt system tiny (a dense
[residuals, ~13C] Jacobian) however many frames are used.  The triangulation is the weighted linear
one of `jaxpose.triangulation`, re-weighted twice by each view's depth, so that its point-to-plane
distances become angular (pixel) errors and the point is close to the reprojection-error optimum.

Each joint's residuals are divided by that joint's noise level, estimated from its residuals each
round (a detector finds a hip to ~3 px and a wrist to ~8 px), so that the squared residuals are
chi-square distributed and the lens priors weigh against them as a posterior would.  The
parameters' 1-sigma uncertainties are the Gauss-Newton posterior's at the solution:
(J_data^T J_data / s^2 + J_prior^T J_prior)^-1, with s^2 the robust residual variance (near 1).

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
import jax.flatten_util
import jax.numpy as jnp
import jaxlie
import numpy as np
import optimistix as optx

from jaxpose.calibration.initial import CalibrationError
from jaxpose.calibration.lens import (
    AT_PRIOR, ESTIMATED, HELD, PRIOR_DOMINATED, LensEstimate, LensSetup, lens_from_theta, sigma_in_units, theta_in_units,
)  # fmt: skip
from jaxpose.camera import Cameras, project_from_camera, project_with_matrices, undistort_compiled, undistort_lens
from jaxpose.triangulation import triangulate

# Depth re-weightings of the triangulation: one already brings the point within a fraction of a
# pixel of the optimum at these baselines; two make it indistinguishable.
REWEIGHTINGS = 2
# Cauchy scale as a multiple of the median residual: inliers keep ~full weight, a swapped joint
# (tens of pixels off) next to none.
CAUCHY_SCALE_PER_MEDIAN = 3.0
GAUGE_WEIGHT = 1e4  # noise sigmas per rig unit of the scale-gauge residual
# Tolerances on the parameters (radians, rig units ~ the first baseline, lens offsets of order one):
# 1e-6 rad is 0.00006 degrees, far below what the detections determine.
SOLVER = optx.LevenbergMarquardt(rtol=1e-5, atol=1e-6)


@dataclasses.dataclass(frozen=True)
class BundleResult:
    """The adjusted rig, in the initial rig's units (view 0 at the origin)."""

    R: np.ndarray
    """f64[C, 3, 3] world-to-camera rotations."""
    t: np.ndarray
    """f64[C, 3] translations."""
    K: np.ndarray
    """f64[C, 3, 3] intrinsics (the given ones, or estimated)."""
    dist: np.ndarray
    """f64[C, 5] distortion of `lens.model` (the given one, or estimated; zeros: none)."""
    lens: LensEstimate
    """Every camera's intrinsics with their 1-sigma and whether given, estimated or left at the prior."""
    points: np.ndarray
    """f64[F, J, 3] the joints the final cameras triangulate."""
    error_px: np.ndarray
    """f64[F, C, J] re-projection error of every observation (NaN where not observed)."""
    weights: np.ndarray
    """f64[F, C, J] the final robust weights (0 where not observed)."""
    residual_scale: float
    """The robust residual variance factor s^2 of the final solution (1: the per-joint noise levels
    explain the residuals exactly)."""


@dataclasses.dataclass(frozen=True)
class _Problem:
    """The fixed data of one adjustment (a pytree of arrays; `model` static)."""

    R0: jax.Array
    t0: jax.Array
    K0: jax.Array
    dist0: jax.Array
    free_index: jax.Array  # i[P] flat indices into theta [C, 7] of the free parameters ("lens" [P])
    active: jax.Array  # bool[P] the free parameters not (yet) put back at their prior
    held: jax.Array  # f64[C, 7] theta of the parameters not free or not active
    prior_mean: jax.Array
    prior_sigma: jax.Array
    pixels: jax.Array  # f64[F, C, J, 2] detections (distorted), the principal point where not observed
    observed: jax.Array  # bool[F, C, J]
    lens_undistorts: bool = True  # static: whether the free parameters move the undistorted detections
    undistorted: jax.Array | None = None  # f64[F, C, J, 2] where they do not: the detections undistorted once


jax.tree_util.register_dataclass(
    _Problem, data_fields=[f.name for f in dataclasses.fields(_Problem) if f.name != "lens_undistorts"], meta_fields=["lens_undistorts"]
)


def _problem(R: np.ndarray, t: np.ndarray, lens: LensSetup, pixels: np.ndarray, observed: np.ndarray) -> _Problem:
    """The adjustment's fixed data (float64: call under `jax.enable_x64`)."""
    centre = np.broadcast_to(lens.K[None, :, None, :2, 2], pixels.shape)
    # An unobserved detection (weight 0) sits at the principal point, where undistortion is trivial.
    pixels = np.where(observed[..., None], pixels, centre).astype(np.float64)
    # The undistortion's fixed-point loop is most of the model's cost.  Without distortion a focal length
    # or principal point moves a pixel and its undistorted position alike (the identity), and with nothing
    # free the lens is fixed: either way the detections are undistorted once, here.
    distorted = bool(np.any(lens.dist != 0.0))
    lens_undistorts = lens.any_free and (distorted or bool(lens.free[:, 3:].any()))
    undistorted = None
    if not lens_undistorts:
        undistorted = np.asarray(undistort_compiled(lens.K, lens.dist, pixels, model=lens.model), np.float64) if distorted else pixels
    C = len(R)
    return _Problem(
        R0=np.asarray(R, np.float64), t0=np.asarray(t, np.float64), K0=lens.K, dist0=lens.dist,
        free_index=np.flatnonzero(lens.free), active=np.ones(int(lens.free.sum()), bool), held=np.zeros((C, 7)),
        prior_mean=lens.prior_mean, prior_sigma=lens.prior_sigma, pixels=pixels, observed=observed,
        lens_undistorts=lens_undistorts, undistorted=undistorted,
    )  # fmt: skip


def _extrinsics(params: dict, problem: _Problem) -> tuple[jax.Array, jax.Array]:
    """(R [C, 3, 3], t [C, 3]); view 0 is the fixed gauge."""
    update = jaxlie.SO3.exp(params["rotation"]).as_matrix()  # [C-1, 3, 3]
    R = jnp.concatenate([problem.R0[:1], update @ problem.R0[1:]])
    return R, jnp.concatenate([problem.t0[:1], params["translation"]])


def _theta(params: dict, problem: _Problem) -> jax.Array:
    if "lens" not in params:
        return problem.held
    held = problem.held.reshape(-1)
    values = jnp.where(problem.active, params["lens"], held[problem.free_index])
    return held.at[problem.free_index].set(values).reshape(problem.held.shape)


def _model(params: dict, problem: _Problem, weights: jax.Array, model: str) -> tuple[jax.Array, jax.Array]:
    """Joints [F, J, 3] triangulated under `weights` [F, C, J], and their re-projections [F, C, J, 2]
    through the lenses (distorted pixels)."""
    R, t = _extrinsics(params, problem)
    K, dist = lens_from_theta(_theta(params, problem), problem.K0, problem.dist0)
    undistorted = undistort_lens(K, dist, problem.pixels, model) if problem.lens_undistorts else problem.undistorted
    P = K @ jnp.concatenate([R, t[..., None]], axis=-1)
    # Triangulation weights multiply distances, the robust weights squared residuals: hence the root.
    row_weights = jnp.sqrt(weights)
    points = triangulate(P, undistorted, row_weights, method="normal")
    for _ in range(REWEIGHTINGS):
        depth = jnp.abs(project_with_matrices(P, points)[..., 2])  # [F, C, J]
        nearest = jnp.max(jnp.where(weights > 0, depth, 0.0), axis=1, keepdims=True)  # keeps weights O(1)
        points = triangulate(P, undistorted, row_weights * nearest / jnp.maximum(depth, 1e-6 * nearest + 1e-30), method="normal")
    camera_points = jnp.einsum("cij,fnj->fcni", R, points) + t[:, None, :]
    # A joint behind a camera (only possible far from the solution) re-projects far away, not to NaN.
    projected = project_from_camera(Cameras(K=K, R=R, t=t, dist=dist, distortion_model=model), camera_points, min_depth=1e-9)
    return points, projected


def _residuals(params: dict, args: tuple) -> tuple[jax.Array, jax.Array, jax.Array]:
    """(data residuals [F * C * J * 2] in noise units, prior residuals [C * 7], scale gauge [1])."""
    problem, weights, joint_sigma, model = args
    _, projected = _model(params, problem, weights, model)
    data = jnp.sqrt(weights)[..., None] * (projected - problem.pixels) / joint_sigma[:, None]
    if "lens" in params:  # only the free parameters have a prior; one put back at it, a residual of 0
        index = problem.free_index
        deviation = (params["lens"] - problem.prior_mean.reshape(-1)[index]) / problem.prior_sigma.reshape(-1)[index]
        prior = jnp.where(problem.active, deviation, 0.0)
    else:
        prior = jnp.zeros(0, problem.held.dtype)
    # The scale gauge: nothing in the images fixes it, so one residual holds view 1's distance from
    # view 0 at its start value (a free null direction lets the solver drift and stalls its stopping test).
    gauge = GAUGE_WEIGHT * (jnp.linalg.norm(params["translation"][0]) - jnp.linalg.norm(problem.t0[1]))
    return data.reshape(-1), prior.reshape(-1), gauge[None]


def _stacked_residuals(params: dict, args: tuple) -> jax.Array:
    return jnp.concatenate(_residuals(params, args))


def _robust_weights(error: jax.Array, observed: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Cauchy weights [F, C, J] from the errors (px), and each joint's noise 1-sigma per coordinate
    (px, [J]) under them, corrected for the 3 coordinates every triangulated joint absorbs."""
    median = jnp.nanmedian(jnp.where(observed, error, jnp.nan))
    scale = CAUCHY_SCALE_PER_MEDIAN * jnp.maximum(median, 1e-6)
    weights = jnp.where(observed, 1.0 / (1.0 + (error / scale) ** 2), 0.0)
    points = (observed.sum(1) >= 2).sum(0)  # [J] triangulated instances of each joint
    freedom = jnp.maximum(2.0 * weights.sum((0, 1)) - 3.0 * points, 1.0)
    joint_sigma = jnp.sqrt(jnp.sum(weights * jnp.where(observed, error, 0.0) ** 2, axis=(0, 1)) / freedom)
    return weights, jnp.maximum(joint_sigma, 1e-3)


def _errors(params: dict, problem: _Problem, weights: jax.Array, model: str) -> tuple[jax.Array, jax.Array]:
    points, projected = _model(params, problem, weights, model)
    return points, jnp.linalg.norm(projected - problem.pixels, axis=-1)


@functools.partial(jax.jit, static_argnames=("max_steps", "model"))
def _reweight_and_solve(params, problem: _Problem, max_steps: int, model: str):
    """One robust round: Cauchy weights and joint noise levels from the current residuals, then
    Levenberg-Marquardt under them."""
    _, error = _errors(params, problem, problem.observed.astype(problem.pixels.dtype), model)
    weights, joint_sigma = _robust_weights(error, problem.observed)
    solution = optx.least_squares(
        _stacked_residuals, SOLVER, params, args=(problem, weights, joint_sigma, model), max_steps=max_steps, throw=False
    )
    return solution.value, weights, joint_sigma


@functools.partial(jax.jit, static_argnames="model")
def _posterior(params, problem: _Problem, weights, joint_sigma, model: str):
    """The posterior covariance of the flattened parameters (in `ravel_pytree` order), the residual
    variance factor s^2, the joints and the errors."""
    flat, unravel = jax.flatten_util.ravel_pytree(params)
    args = (problem, weights, joint_sigma, model)
    jacobians = jax.jacfwd(lambda x: _residuals(unravel(x), args))(flat)
    data, prior, gauge = (jnp.asarray(j) for j in jacobians)
    residual = _residuals(params, args)[0]
    points = (weights.sum(1) > 0).sum()
    freedom = jnp.maximum(2.0 * weights.sum() - 3.0 * points - flat.size, 1.0)
    variance = jnp.sum(residual**2) / freedom
    information = data.T @ data / variance + prior.T @ prior + gauge.T @ gauge
    # Held parameters have no information; a unit diagonal there keeps the inverse defined (and unused).
    held = jnp.all(data == 0.0, axis=0) & jnp.all(prior == 0.0, axis=0) & jnp.all(gauge == 0.0, axis=0)
    covariance = jnp.linalg.inv(information + jnp.diag(held.astype(information.dtype)))
    points3d, error = _errors(params, problem, weights, model)
    return covariance, variance, points3d, error


@jax.jit
def _rig(params, problem: _Problem):
    """(R, t, theta, K, dist) of the adjusted parameters."""
    R, t = _extrinsics(params, problem)
    theta = _theta(params, problem)
    return R, t, theta, *lens_from_theta(theta, problem.K0, problem.dist0)


def _lens_sigma(covariance: np.ndarray, params: dict, free: np.ndarray) -> np.ndarray:
    """f64[C, 7] posterior 1-sigma of the lens offsets theta (0 where not free)."""
    sigma = np.zeros(free.shape)
    if "lens" in params:
        sizes = {name: int(np.size(value)) for name, value in params.items()}
        # ravel_pytree orders a dict's entries by sorted key.
        offset = sum(sizes[name] for name in sorted(params) if name < "lens")
        diagonal = np.diag(covariance)[offset : offset + sizes["lens"]]
        sigma[free] = np.sqrt(np.maximum(diagonal, 0.0))
    return sigma


def bundle_adjust(
    R: np.ndarray,
    t: np.ndarray,
    lens: LensSetup,
    pixels: np.ndarray,
    observed: np.ndarray,
    rounds: int = 4,
    max_steps: int = 50,
) -> BundleResult:
    """Refine a rig (R [C, 3, 3], t [C, 3], view 0 = identity, origin) and its lenses' free
    intrinsics on detections [F, C, J, 2] (distorted pixels) observed where `observed` [F, C, J].

    After the robust rounds, a free lens parameter whose posterior 1-sigma is at least
    `PRIOR_DOMINATED` of its prior's is held at its prior mean and the last round solved again.
    """
    C = R.shape[0]
    # float64: the loss sums ~1e5 squared pixel residuals, whose float32 sum cannot resolve the
    # sub-pixel improvements that separate a 0.1 degree rotation error from a 1 degree one.
    # Everything below is numpy between the compiled functions: run op by op, JAX would compile a
    # program for every operation.
    with jax.enable_x64(True):
        params = {"rotation": np.zeros((C - 1, 3)), "translation": np.asarray(t[1:], np.float64)}
        if lens.any_free:
            params["lens"] = np.zeros(int(lens.free.sum()))  # the start
        problem = _problem(R, t, lens, pixels, observed)
        for _ in range(rounds):
            params, weights, joint_sigma = _reweight_and_solve(params, problem, max_steps, lens.model)
        covariance, variance, points, error = _posterior(params, problem, weights, joint_sigma, lens.model)
        sigma = _lens_sigma(np.asarray(covariance), params, lens.free)
        at_prior = lens.free & (sigma >= PRIOR_DOMINATED * lens.prior_sigma)
        if at_prior.any():
            # Same shapes, so no new compilation: the parameters put back are masked, not removed.
            problem = dataclasses.replace(problem, active=~at_prior[lens.free], held=np.where(at_prior, lens.prior_mean, 0.0))
            params, weights, joint_sigma = _reweight_and_solve(params, problem, max_steps, lens.model)
            # The 1-sigmas of the others keep the put-back parameters' prior uncertainty (k1's must
            # not pretend that k2 is known to be 0): the posterior with them free at their prior mean.
            marginal = dict(params, lens=np.where(problem.active, np.asarray(params["lens"]), lens.prior_mean[lens.free]))
            everything = dataclasses.replace(problem, active=np.ones_like(problem.active))
            covariance, variance, points, error = _posterior(marginal, everything, weights, joint_sigma, lens.model)
            sigma = _lens_sigma(np.asarray(covariance), params, lens.free)
        R_out, t_out, theta, K_out, dist_out = (np.asarray(a) for a in _rig(params, problem))
    if not all(np.all(np.isfinite(np.asarray(a))) for a in (R_out, t_out, K_out, dist_out)):
        raise CalibrationError("the bundle adjustment diverged (non-finite cameras); check the detections' views and names")
    state = np.where(lens.free, np.where(at_prior, AT_PRIOR, ESTIMATED), HELD)
    sigma = np.where(at_prior, lens.prior_sigma, np.where(lens.free, sigma, 0.0))
    estimate = LensEstimate(
        value=theta_in_units(theta, lens.K, lens.dist),
        sigma=sigma_in_units(sigma, theta, lens.K),
        prior_mean=theta_in_units(lens.prior_mean, lens.K, lens.dist),
        prior_sigma=np.where(lens.free, sigma_in_units(lens.prior_sigma, lens.prior_mean, lens.K), 0.0),
        state=state,
    )
    error = np.where(observed, np.asarray(error, np.float64), np.nan)
    return BundleResult(
        R=np.asarray(R_out, np.float64), t=np.asarray(t_out, np.float64), K=np.asarray(K_out, np.float64),
        dist=np.asarray(dist_out, np.float64), lens=estimate, points=np.asarray(points, np.float64), error_px=error,
        weights=np.asarray(weights, np.float64), residual_scale=float(variance),
    )  # fmt: skip
