"""A recording's motion solved over time: the per-instant evidence, a motion prior, constant limb lengths.

`jaxpose.reconstruction.fusion` estimates each instant alone: every joint's position y_tj with its
posterior covariance S_tj (`Fusion.covariance`), which already weighs the rays and the lifts.  Here the
whole recording's track x_tj (world mm) is the minimum of

    sum_tj  w_tj (x_tj - y_tj)^T S_tj^-1 (x_tj - y_tj)                 the evidence, robustly weighted
  + sum_tj  u_tj |x_t+1,j - 2 x_tj + x_t-1,j|^2 / q_j^2                a constant-velocity prior
  + sum_tb  (|x_tc - x_tp| - L_b)^2 / limb_sigma^2                     each limb b = (c, p) of length L_b

- The motion prior: each joint's acceleration (second difference) is white noise of q_j mm/s^2 per
  axis, q_j / fps^2 in mm per frame^2: in physical units, so that the frame rate changes nothing but
  the noise per frame.  Where no evidence is (no camera sees the person), the minimum is the smoothest
  bridge between the ends, and its uncertainty grows toward the middle of the gap (a cubic spline's,
  not a straight line's held certainty).
- The prior set by the recording (`acceleration_mm_s2` None, the default; a number fixes it for every
  joint): q_j maximises the marginal likelihood of joint j's evidence under the linear-Gaussian
  state-space model (the evidence y_tj ~ N(x_tj, S_tj), the second differences ~ N(0, q_j^2 / fps^4)
  per axis, the first two frames free), `process_noise`.  A recording of walking gets a few m/s^2, a
  jog or a dance tens to hundreds: one number chosen on slow motion lags fast motion and cuts its peaks.
- Heavy tails where bodies have them (a foot strike, a punch): each acceleration is Student-t with
  `acceleration_dof` degrees of freedom, solved by EM: u_tj = (nu + 3) / (nu + |a_tj|^2 / q_j^2),
  recomputed with the evidence's weights at every iteration, so that one sharp acceleration is not
  spread over its neighbours (`Trajectory.impact_weight`: below 0.5 an impact).
- The limbs: L_b is the median length over the instants where two or more views triangulate both
  joints (the recording's own body, not a generic one); over those where both are at least fused
  where fewer than `MIN_LENGTH_INSTANTS` are; a limb never seen so is left free.
- The evidence: a cell whose joint no view detects (LIFTED) keeps its part, its covariance scaled by
  `lifted_sigma_scale`^2; each cell's weight w_tj is the Cauchy weight of its Mahalanobis residual
  (`robust_sigmas`), recomputed at every iteration (iteratively re-weighted least squares): an instant
  whose fused point jumps away from the motion counts little.

The limb term is nonlinear: Gauss-Newton, linearised about the current track (|d| ~ u^T d, u = d / |d|,
so each limb says u^T (x_c - x_p) = L_b), with the re-weighting in the same loop, `iterations` times.
Each linear solve is a conjugate-gradient solve of the 3FJ normal equations, preconditioned by each
joint's own system (its evidence, its motion prior and its limbs' diagonal blocks: banded, 8 above the
diagonal in the order (frame, axis), Cholesky-factored by `scipy.linalg.cholesky_banded`): linear in
the frames and joints; the cameras were already reduced per joint by the fusion.

A recording longer than `WINDOW_FRAMES` + 2 `CONTEXT_FRAMES` frames is solved in windows of
`WINDOW_FRAMES` frames, each with `CONTEXT_FRAMES` frames of its neighbours on either side (solved and
dropped): the same track to ~0.001 mm where the prior is fixed and the smoother's reach (`CONTEXT_FRAMES`)
short against the context, each window's estimated prior its own (`Trajectory.acceleration_mm_s2` then the
frame-weighted geometric mean), memory flat in the recording's length.

Uncertainty (`Trajectory.sigma`): sqrt(trace) of each cell's marginal posterior covariance under each
joint's own system (the other joints held where they are), from the banded factor by the selected
inversion (Takahashi's recurrence), O(F) per joint.

The marginal likelihood of joint j's evidence, up to a constant (the prior on the first two frames flat):

    log p(y | q) = -1/2 min_x [evidence + motion terms] - 1/2 log det A(q) - 3 (F - 2) log(q / fps^2)

with A(q) the joint's own system (no limbs), both from its banded Cholesky factor: O(F) per joint and
value of q, evaluated on `NOISE_GRID_MM_S2`, refined by a parabola in log q about the best value, each
joint's estimate then pooled toward the joints' mean with the weight of `POOL_ACCELERATIONS` accelerations
(a joint seen at few instants takes the body's).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import scipy.sparse
from scipy.linalg import cho_solve_banded, cholesky_banded

from jaxpose.reconstruction.fusion import Provenance

MIN_LENGTH_INSTANTS = 10  # instants of triangulated limbs below which the fused ones measure its length
MIN_EVIDENCE_CELLS = 2  # a joint with fewer cells of evidence keeps its per-instant values (the prior fixes no line)
BAND = 8  # the upper bandwidth of one joint's system in the order (frame, axis): 2 frames of 3 axes, +2 within one
CG_TOLERANCE = 1e-9  # relative residual of the conjugate gradients
CG_MAX_STEPS = 500
NOISE_GRID_MM_S2 = np.geomspace(100.0, 1e6, 13)  # from a body at rest to the peaks of sprinting and punching
POOL_ACCELERATIONS = 20.0  # a joint's estimate weighs as much as this many 3D accelerations of the body's mean
# The per-frame process noise is held at least this fraction of the evidence's own noise per axis (the median
# over the joint's cells): tighter (--fps 1e5..1e9), float64's banded Cholesky loses the evidence against the
# prior and fails as not positive definite, while the track is a constant-velocity line to within this fraction
# of the evidence's noise over the ~1/sqrt(fraction) frames such a prior bends over.  Reached only above ~1000 fps.
MIN_NOISE_FRACTION = 1e-4
# A long recording is solved in windows of this many frames, each with this many frames of context on either
# side (solved, then dropped): the normal equations' memory (~42 KB a frame of 17 joints) stays that of one
# window.  The smoother reaches ~(sigma / q-per-frame)^(1/2) frames (sigma the evidence's noise), its influence
# falling as exp(-frames / (1.4 reach)): ~16 frames at 50 fps and the grid's bottom, 100 mm/s^2, with 10 mm
# evidence, and the context is 25 such reaches; a gap of at most --max-gap frames adds its length.
WINDOW_FRAMES = 2000
CONTEXT_FRAMES = 400
# Re-weightings of the evidence alone before the accelerations' (EM) weights join in: from the Gaussian prior's
# track an outlier instant looks as much like three sharp accelerations as like a bad detection, and the
# re-weighting would keep it half way; once the outliers have their low weights an impact is one acceleration.
SETTLE_ITERATIONS = 2


@dataclasses.dataclass(frozen=True)
class TrajectoryConfig:
    """The trajectory's model (module docstring): the acceleration's degrees of freedom chosen on CMU subject
    02's motion, the other settings on the Human3.6M development split's training recordings (with the
    process noise fixed at 3000 mm/s^2 then; docs/reconstruction.md), not on the reported ones."""

    acceleration_mm_s2: float | None = None
    """The motion prior's process noise: a joint's acceleration, scale per axis (mm/s^2); None: estimated
    from each recording per joint (`process_noise`), a number: that one for every recording and joint."""
    acceleration_dof: float = 4.0
    """The Student-t degrees of freedom of the acceleration (heavy tails at impacts); inf: Gaussian."""
    limb_sigma_mm: float = 10.0
    """How far a limb's length may stray from its median over the recording (mm)."""
    robust_sigmas: float = 3.0
    """The Cauchy scale of an instant's residual from the track (its Mahalanobis distance, standard deviations)."""
    lifted_sigma_scale: float = 4.0
    """A factor on the uncertainty of a joint no view detects (the lifts alone): the fusion's model of the
    lifter says ~90 mm, while such joints are ~150 mm off on Human3.6M."""
    iterations: int = 5
    """Gauss-Newton / re-weighting iterations after the first solve."""

    def __post_init__(self):
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if field.name == "acceleration_mm_s2" and value is None:
                continue
            if not (isinstance(value, (int, float)) and value > 0 and (np.isfinite(value) or field.name == "acceleration_dof")):
                raise ValueError(f"TrajectoryConfig.{field.name} must be a positive number, got {value!r}")
        if not isinstance(self.iterations, int):
            raise ValueError(f"TrajectoryConfig.iterations must be a whole number, got {self.iterations!r}")


@dataclasses.dataclass(frozen=True)
class Trajectory:
    """A recording's track of F frames and J joints.

    points:             f32[F, J, 3] world mm at every frame (the bridge where there is no evidence; a joint
                        with fewer than `MIN_EVIDENCE_CELLS` cells of evidence: its input values).
    sigma:              f32[F, J] mm, the posterior RMS 3D error (module docstring); NaN where not solved.
    weight:             f32[F, J] each cell's final robust weight; 0 where it had no evidence.
    limb_lengths:       f32[B] mm, the length each limb (`bones`' order) was held to; NaN where free.
    acceleration_mm_s2: f32[J] the process noise each joint was solved with (mm/s^2, per axis); NaN where
                        not solved.
    impact_weight:      f32[F, J] the final Student-t weight u_tj of the acceleration at each frame (1 at the
                        first and last frames and where not solved): below 0.5, an impact the prior let through.
    """

    points: np.ndarray
    sigma: np.ndarray
    weight: np.ndarray
    limb_lengths: np.ndarray
    acceleration_mm_s2: np.ndarray
    impact_weight: np.ndarray


def limb_lengths(points: np.ndarray, provenance: np.ndarray, bones: Sequence[tuple[int, int]]) -> np.ndarray:
    """f64[B]: each limb's median length (mm) over the instants where both its joints are TRIANGULATED, or
    else (fewer than `MIN_LENGTH_INSTANTS`) at least FUSED; NaN where neither has enough."""
    lengths = np.full(len(bones), np.nan)
    for rank in (Provenance.FUSED, Provenance.TRIANGULATED):  # the stricter last: it wins where it can
        trusted = (provenance >= rank) & (provenance != Provenance.INTERPOLATED)
        for b, (child, parent) in enumerate(bones):
            both = trusted[:, child] & trusted[:, parent]
            if both.sum() >= MIN_LENGTH_INSTANTS:
                lengths[b] = np.median(np.linalg.norm(points[both, child] - points[both, parent], axis=-1))
    return lengths


@dataclasses.dataclass(frozen=True)
class _Evidence:
    """The evidence as the solve weighs it: precision [F, J, 3, 3] (LIFTED cells' scaled; a unit dummy for
    the joints not solved), observed [F, J, 3] (0 where none), has [F, J], solved [J], and floor [J] mm/frame^2:
    `MIN_NOISE_FRACTION` of each joint's median evidence noise per axis."""

    precision: np.ndarray
    observed: np.ndarray
    has: np.ndarray
    solved: np.ndarray
    floor: np.ndarray

    @property
    def dummy(self) -> np.ndarray:
        """bool[F, J]: the cells of the joints not solved, held at 0 by unit weights so that their systems stay regular."""
        return np.broadcast_to(~self.solved, self.has.shape)

    def per_frame(self, noise_mm_s2: np.ndarray, fps: float) -> np.ndarray:
        """f64[J] mm/frame^2: the process noise per frame, held at the floor (`MIN_NOISE_FRACTION`)."""
        return np.maximum(np.asarray(noise_mm_s2, np.float64) / fps**2, self.floor)


def _evidence(points, covariance, provenance, config: TrajectoryConfig) -> _Evidence:
    """The evidence's precisions (the LIFTED cells' scaled), the cells that have some, the joints solved."""
    F, J, _ = points.shape
    has = np.isfinite(points).all(-1) & np.isfinite(covariance).all((-1, -2))
    scale = np.where(provenance == Provenance.LIFTED, config.lifted_sigma_scale**2, 1.0)
    precision = np.zeros((F, J, 3, 3))
    precision[has] = np.linalg.inv(covariance[has] * scale[has][:, None, None])
    solved = has.sum(0) >= MIN_EVIDENCE_CELLS  # [J]
    precision[:, ~solved] = np.eye(3)  # a dummy system for the joints left as they are, replaced below
    variance = np.full((F, J), np.nan)
    variance[has] = np.trace(covariance[has] * scale[has][:, None, None], axis1=-2, axis2=-1) / 3.0
    median = np.ones(J)
    median[has.any(0)] = np.nanmedian(variance[:, has.any(0)], axis=0)
    return _Evidence(precision, np.where(has[..., None], points, 0.0), has, solved, MIN_NOISE_FRACTION * np.sqrt(median))


def _checked(points, covariance, provenance, fps):
    """The evidence as float64 arrays, refused in one line where its shapes or the frame rate are wrong."""
    points = np.asarray(points, np.float64)
    covariance = np.asarray(covariance, np.float64)
    F, J, _ = points.shape
    if points.shape[-1] != 3 or covariance.shape != (F, J, 3, 3) or np.shape(provenance) != (F, J):
        raise ValueError(
            f"solve_trajectory: points [F, J, 3], covariance [F, J, 3, 3] and provenance [F, J] expected, got"
            f" {points.shape}, {covariance.shape}, {np.shape(provenance)}"
        )
    if not 0 < fps < np.inf:
        raise ValueError(f"solve_trajectory: fps must be a positive finite number, got {fps}")
    return points, covariance


def process_noise(
    points: np.ndarray, covariance: np.ndarray, provenance: np.ndarray, fps: float, config: TrajectoryConfig = TrajectoryConfig()
) -> np.ndarray:
    """f64[J] mm/s^2: each joint's process noise estimated from its evidence (module docstring: the
    marginal likelihood on `NOISE_GRID_MM_S2`, a parabola in log q, pooled toward the joints' mean);
    NaN for a joint with fewer than `MIN_EVIDENCE_CELLS` cells.  Arguments as `solve_trajectory`'s."""
    points, covariance = _checked(points, covariance, provenance, fps)
    evidence = _evidence(points, covariance, provenance, config)
    return _estimated_noise(evidence, evidence.has.astype(np.float64), fps)


def _estimated_noise(evidence: _Evidence, weight: np.ndarray, fps: float) -> np.ndarray:
    """`process_noise` of the evidence with its cells weighted by `weight` [F, J] (the robust weights)."""
    F, J = weight.shape
    if F < 3 or not evidence.solved.any():  # no acceleration to measure
        return np.where(evidence.solved, NOISE_GRID_MM_S2[len(NOISE_GRID_MM_S2) // 2], np.nan)
    weight = np.where(evidence.dummy, 1.0, weight)
    blocks = weight[..., None, None] * evidence.precision
    rhs = np.einsum("fjab,fjb->fja", blocks, evidence.observed)
    fit = np.einsum("fja,fja->j", evidence.observed, rhs)  # y^T P y per joint
    # The system is the evidence's bands plus the motion prior's of unit weight times 1 / q^2 per joint:
    # both built once, each value of the grid only factors their sum.
    evidence_bands = _bands(blocks, np.zeros((F - 2, J)))
    motion_bands = _bands(np.zeros_like(blocks), np.ones((F - 2, J)))
    rhs = rhs.swapaxes(0, 1).reshape(J, -1)  # joint-major, as the factor
    likelihood = []
    for noise in NOISE_GRID_MM_S2:
        per_frame = evidence.per_frame(np.full(J, noise), fps)
        factors = _factor(evidence_bands + motion_bands * (1.0 / per_frame**2)[:, None])
        solved = cho_solve_banded((factors, False), rhs.ravel(), check_finite=False).reshape(J, F * 3)
        cost = fit - np.einsum("jn,jn->j", rhs, solved)
        log_determinant = 2.0 * np.log(factors[BAND].reshape(J, -1)).sum(-1)
        likelihood.append(-0.5 * cost - 0.5 * log_determinant - 3.0 * (F - 2) * np.log(per_frame))
    likelihood = np.array(likelihood)  # [grid, J]
    step = np.log(NOISE_GRID_MM_S2[1] / NOISE_GRID_MM_S2[0])
    best = np.clip(np.argmax(likelihood, 0), 1, len(NOISE_GRID_MM_S2) - 2)
    below, at, above = (likelihood[best + k, np.arange(J)] for k in (-1, 0, 1))
    curvature = np.maximum(-(above - 2.0 * at + below) / step**2, 0.0)  # -d^2 log p / d(log q)^2
    shift = np.where(curvature > 0, 0.5 * (above - below) / np.maximum(curvature * step, 1e-300), 0.0)
    log_noise = np.log(NOISE_GRID_MM_S2[best]) + np.clip(shift, -step, step)
    log_noise = np.clip(log_noise, np.log(NOISE_GRID_MM_S2[0]), np.log(NOISE_GRID_MM_S2[-1]))
    # Pooled: 6 = -d^2/d(log q)^2 of one 3D acceleration seen exactly (2 per axis).
    mean = log_noise[evidence.solved].mean()
    prior = 6.0 * POOL_ACCELERATIONS
    pooled = (curvature * log_noise + prior * mean) / (curvature + prior)
    return np.where(evidence.solved, np.exp(pooled), np.nan)


def solve_trajectory(
    points: np.ndarray,
    covariance: np.ndarray,
    provenance: np.ndarray,
    bones: Sequence[tuple[int, int]],
    fps: float,
    config: TrajectoryConfig = TrajectoryConfig(),
    lengths: np.ndarray | None = None,
    noise: np.ndarray | None = None,
) -> Trajectory:
    """The track (module docstring) of one recording's per-instant evidence.

    points:     [F, J, 3] world mm, consecutive frames; NaN where no evidence.
    covariance: [F, J, 3, 3] mm^2, the evidence's covariance (`Fusion.covariance`); NaN where none.
    provenance: [F, J] `Provenance` of the evidence: limb lengths from the TRIANGULATED cells, the
                LIFTED cells' covariance scaled by `lifted_sigma_scale`^2.
    bones:      (child, parent) joint pairs (`Skeleton.bones`), the limbs held at constant length.
    fps:        frames per second (the process noise is per second^2).
    lengths:    [B] mm, the limbs' lengths (NaN: free) where measured on more than these frames (a part of
                a recording); None: `limb_lengths` of this evidence.
    noise:      [J] mm/s^2, each joint's process noise where estimated on more than these frames; None:
                `config.acceleration_mm_s2`, or where that is None estimated from this evidence (first
                with every cell's weight 1, again with the robust weights of the first solve).

    A recording longer than `WINDOW_FRAMES` + 2 `CONTEXT_FRAMES` is solved window by window (module docstring).
    """
    points, covariance = _checked(points, covariance, provenance, fps)
    provenance = np.asarray(provenance)
    F, J, _ = points.shape
    lengths = limb_lengths(points, provenance, bones) if lengths is None else np.asarray(lengths, np.float64)
    if F <= WINDOW_FRAMES + 2 * CONTEXT_FRAMES:
        return _solve_window(points, covariance, provenance, bones, fps, config, lengths, noise)
    parts = []
    for start in range(0, F, WINDOW_FRAMES):
        stop = min(start + WINDOW_FRAMES, F)
        first, last = max(start - CONTEXT_FRAMES, 0), min(stop + CONTEXT_FRAMES, F)
        window = slice(first, last)
        solved = _solve_window(points[window], covariance[window], provenance[window], bones, fps, config, lengths, noise)
        core = slice(start - first, stop - first)
        parts.append((stop - start, solved.points[core], solved.sigma[core], solved.weight[core], solved.acceleration_mm_s2, solved.impact_weight[core]))
    frames = np.array([part[0] for part in parts], np.float64)[:, None]
    with np.errstate(invalid="ignore"):  # a joint solved in no window: NaN
        noise = np.exp(np.nansum(frames * np.log(np.stack([part[4] for part in parts])), 0) / np.sum(frames * np.isfinite(np.stack([part[4] for part in parts])), 0))
    return Trajectory(
        *(np.concatenate([part[k] for part in parts]) for k in (1, 2, 3)), lengths.astype(np.float32), noise.astype(np.float32),
        np.concatenate([part[5] for part in parts]),
    )


def _solve_window(points, covariance, provenance, bones, fps, config, lengths, noise) -> Trajectory:
    """`solve_trajectory` of a recording (or a window of one) in one system."""
    F, J, _ = points.shape
    evidence = _evidence(points, covariance, provenance, config)
    solved, has, dummy = evidence.solved, evidence.has, evidence.dummy
    limbs = [(b, c, p) for b, (c, p) in enumerate(bones) if np.isfinite(lengths[b]) and solved[c] and solved[p]]
    system = _System(evidence.precision, evidence.observed, has, 1.0 / config.limb_sigma_mm**2, limbs)

    weight = (has | dummy).astype(np.float64)
    estimate = noise is None and config.acceleration_mm_s2 is None
    if noise is None:
        noise = _estimated_noise(evidence, weight, fps) if estimate else np.full(J, config.acceleration_mm_s2)
    noise = np.where(solved, noise, np.nanmean(noise) if solved.any() else 1.0)
    per_frame = evidence.per_frame(noise, fps)
    impact = np.ones((max(F - 2, 0), J))
    track = system.solve(weight, impact / per_frame**2, lengths, None)
    for iteration in range(config.iterations):
        residual = evidence.observed - track
        mahalanobis = np.sqrt(np.maximum(np.einsum("fja,fjab,fjb->fj", residual, evidence.precision, residual), 0.0))
        weight = np.where(dummy, 1.0, np.where(has, 1.0 / (1.0 + (mahalanobis / config.robust_sigmas) ** 2), 0.0))
        if estimate and iteration == 0:  # the outliers the first solve found no longer count as motion
            noise = np.where(solved, _estimated_noise(evidence, weight, fps), noise)
            per_frame = evidence.per_frame(noise, fps)
        if iteration >= SETTLE_ITERATIONS:
            impact = _impact_weights(track, per_frame, config.acceleration_dof)
        track = system.solve(weight, impact / per_frame**2, lengths, track)
    sigma = system.marginal_sigma(weight, impact / per_frame**2, track)
    track = np.where(solved[None, :, None], track, points)
    impact_weight = np.ones((F, J))
    impact_weight[1 : F - 1] = np.where(solved, impact, 1.0)[: max(F - 2, 0)]
    return Trajectory(
        track.astype(np.float32),
        np.where(solved[None], sigma, np.nan).astype(np.float32),
        np.where(has & solved[None], weight, 0.0).astype(np.float32),
        lengths.astype(np.float32),
        np.where(solved, noise, np.nan).astype(np.float32),
        impact_weight.astype(np.float32),
    )


def _impact_weights(track: np.ndarray, per_frame: np.ndarray, dof: float) -> np.ndarray:
    """f64[F - 2, J]: the EM weight (nu + 3) / (nu + |a|^2 / q^2) of each acceleration a of the track
    under the Student-t prior of scale q per axis (mm/frame^2) and nu degrees of freedom (inf: all 1)."""
    acceleration = track[2:] - 2.0 * track[1:-1] + track[:-2]
    if np.isinf(dof):
        return np.ones(acceleration.shape[:2])
    return (dof + 3.0) / (dof + np.einsum("fja,fja->fj", acceleration, acceleration) / per_frame**2)


class _System:
    """The normal equations of the module docstring, for given robust weights, motion weights and a
    linearisation of the limbs.  Unknowns x [F, J, 3]; the solve works on them joint-major ([J, F, 3] as one
    vector of 3FJ), the order of the preconditioner's banded factor, so that no step transposes them.

    The matrix is each joint's own system (`_bands`: its cells' blocks, its limbs' u u^T, the motion prior)
    and the limbs' couplings -u u^T between joints, held as CSR: its pattern is the same at every solve of a
    recording, so it is built once here and each solve only gathers the values into it."""

    def __init__(self, precision, observed, has, limb_weight: float, limbs):
        self.precision, self.observed, self.has = precision, observed, has
        self.limb_weight, self.limbs = limb_weight, limbs
        F, J = has.shape
        n = 3 * F
        # The band within each joint (both triangles): value bands[BAND + i - k, j n + k] at (j n + i, j n + k),
        # i <= k, where it can be nonzero: within a frame's block, or the same axis (the motion prior) across frames.
        offset, column = np.meshgrid(np.arange(BAND + 1), np.arange(n), indexing="ij")  # offset = k - i
        inside = (column - offset >= 0) & (((column - offset) // 3 == column // 3) | (offset % 3 == 0))
        offset, column = offset[inside], column[inside]
        base = np.arange(J)[:, None] * n
        upper_rows, upper_columns = (base + (column - offset)).ravel(), (base + column).ravel()
        upper_source = ((BAND - offset) * J * n + base + column).ravel()
        strict = np.tile(offset > 0, J)
        rows = [upper_rows, upper_columns[strict]]
        columns = [upper_columns, upper_rows[strict]]
        source = [upper_source, upper_source[strict]]
        # The couplings: limb l's -u u^T [F, 3, 3] at (child's cell, parent's cell) and its transpose.
        frame, a, b = (index.ravel() for index in np.meshgrid(np.arange(F), np.arange(3), np.arange(3), indexing="ij"))
        for number, (_, child, parent) in enumerate(limbs):
            value = (BAND + 1) * J * n + number * 9 * F + 9 * frame + 3 * a + b
            rows += [child * n + 3 * frame + a, parent * n + 3 * frame + a]
            columns += [parent * n + 3 * frame + b, child * n + 3 * frame + b]
            source += [value, value]
        rows, columns, source = np.concatenate(rows), np.concatenate(columns), np.concatenate(source)
        order = np.lexsort((columns, rows))
        self._indices, self._gather = columns[order].astype(np.int32), source[order]
        self._indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=J * n))]).astype(np.int32)

    def _limb_rows(self, track) -> np.ndarray:
        """[L, F, 3]: sqrt(limb weight) u, u each limb's unit direction at `track` (0 where degenerate, and
        all 0 before there is a track): the linearised limb rows sqrt(w) u^T (x_c - x_p) = sqrt(w) L_b."""
        if track is None or not self.limbs:
            return np.zeros((len(self.limbs), len(self.has), 3))
        index = np.array(self.limbs)
        difference = track[:, index[:, 1]] - track[:, index[:, 2]]  # [F, L, 3]
        norm = np.linalg.norm(difference, axis=-1, keepdims=True)
        direction = np.where(norm > 1e-6, difference / np.maximum(norm, 1e-6), 0.0)
        return np.sqrt(self.limb_weight) * direction.swapaxes(0, 1)

    def _diagonal_blocks(self, weight, rows) -> np.ndarray:
        """[F, J, 3, 3]: each cell's own block: its weighted evidence and its limbs' u u^T."""
        blocks = weight[..., None, None] * self.precision
        for (_, child, parent), row in zip(self.limbs, rows):
            outer = row[:, :, None] * row[:, None, :]
            blocks[:, child] += outer
            blocks[:, parent] += outer
        return blocks

    def _matrix(self, bands, rows) -> scipy.sparse.csr_matrix:
        """The whole normal matrix (joint-major): the joints' systems `bands` and the limbs' couplings."""
        values = np.concatenate([bands.ravel(), -(rows[..., :, None] * rows[..., None, :]).ravel()])
        n = len(self._indptr) - 1
        return scipy.sparse.csr_matrix((values[self._gather], self._indices, self._indptr), shape=(n, n))

    def solve(self, weight, motion_weight, lengths, track) -> np.ndarray:
        """[F, J, 3]: the minimum of the linearised problem (conjugate gradients, `_factor` preconditioning)."""
        rows = self._limb_rows(track)
        bands = _bands(self._diagonal_blocks(weight, rows), motion_weight)
        rhs = np.einsum("fjab,fjb->fja", weight[..., None, None] * self.precision, self.observed)
        for (b, child, parent), row in zip(self.limbs, rows):
            rhs[:, child] += row * np.sqrt(self.limb_weight) * lengths[b]
            rhs[:, parent] -= row * np.sqrt(self.limb_weight) * lengths[b]
        matrix, factors = self._matrix(bands, rows), _factor(bands)
        F, J, _ = rhs.shape

        def precondition(r):  # the joints' systems side by side: one banded matrix, joint-major
            return cho_solve_banded((factors, False), r, check_finite=False)

        rhs = rhs.swapaxes(0, 1).ravel()
        x = precondition(rhs) if track is None else track.swapaxes(0, 1).flatten()
        residual = rhs - matrix @ x
        z = precondition(residual)
        direction, rz = z, _dot(residual, z)
        target = CG_TOLERANCE**2 * _dot(rhs, rhs)
        for _ in range(CG_MAX_STEPS):
            if _dot(residual, residual) <= target:
                break
            product = matrix @ direction
            step = rz / _dot(direction, product)
            x += step * direction
            residual -= step * product
            z = precondition(residual)
            rz, previous = _dot(residual, z), rz
            direction = z + (rz / previous) * direction
        return np.ascontiguousarray(x.reshape(J, F, 3).swapaxes(0, 1))

    def marginal_sigma(self, weight, motion_weight, track) -> np.ndarray:
        """f64[F, J]: sqrt(trace) of each cell's marginal covariance under its joint's own system."""
        factors = _factors(self._diagonal_blocks(weight, self._limb_rows(track)), motion_weight)
        factors = factors.reshape(BAND + 1, len(weight[0]), -1).swapaxes(0, 1)  # [J, BAND + 1, 3F]
        return np.sqrt(np.trace(_selected_blocks(factors), axis1=-2, axis2=-1)).T


def _bands(blocks: np.ndarray, motion_weight: np.ndarray) -> np.ndarray:
    """[BAND + 1, J, 3F]: each joint's system (its blocks [F, J, 3, 3] and the motion prior of weights
    [F - 2, J]) in LAPACK's upper band storage, ab[BAND + i - k, k] = A[i, k] for i <= k, unknowns in the
    order (frame, axis); joint after joint, so that [BAND + 1, 3FJ] is one banded matrix of them all."""
    F, J = blocks.shape[:2]
    ab = np.zeros((BAND + 1, J, 3 * F))
    for a in range(3):
        for b in range(a, 3):
            ab[BAND + a - b, :, b::3] = blocks[:, :, a, b].T
    if F < 3:  # no second difference
        return ab
    # D^T W D per axis: its diagonal and the two bands above it, 3 and 6 apart in the (frame, axis) order.
    w = np.asarray(motion_weight, np.float64).T  # [J, F - 2]
    diagonal, first, second = np.zeros((J, F)), np.zeros((J, F - 1)), np.zeros((J, F - 2))
    stencil = np.array([1.0, -2.0, 1.0])
    for i in range(3):
        diagonal[:, i : F - 2 + i] += stencil[i] ** 2 * w
    for i in range(2):
        first[:, i : F - 2 + i] += stencil[i] * stencil[i + 1] * w
    second += stencil[0] * stencil[2] * w
    for a in range(3):
        ab[BAND, :, a::3] += diagonal
        ab[BAND - 3, :, 3 + a :: 3] += first
        ab[BAND - 6, :, 6 + a :: 3] += second
    return ab


def _factor(bands: np.ndarray) -> np.ndarray:
    """[BAND + 1, 3FJ]: the banded Cholesky factor of every joint's system [BAND + 1, J, 3F] (`_bands`), joint
    after joint (block diagonal: `_bands` leaves the entries above each joint's first rows 0)."""
    return cholesky_banded(bands.reshape(BAND + 1, -1), lower=False, check_finite=False)


def _factors(blocks: np.ndarray, motion_weight: np.ndarray) -> np.ndarray:
    """[BAND + 1, 3FJ]: `_factor` of the system of these blocks and motion weights."""
    return _factor(_bands(blocks, motion_weight))


def _dot(a: np.ndarray, b: np.ndarray) -> float:
    """a . b of two vectors, without BLAS: its threads only contend on the small vectors of one recording."""
    return float(np.einsum("i,i->", a, b))


def _selected_blocks(factors: np.ndarray) -> np.ndarray:
    """[J, F, 3, 3]: the diagonal 3x3 blocks of A^-1 for A = U^T U, U upper banded ([J, BAND + 1, 3F],
    LAPACK storage), frame by frame from the last (Takahashi's recurrence in blocks of one frame).

    U Z = U^-T is block lower triangular with diagonal blocks U_tt^-T, so for s >= t:
    Z_ts = U_tt^-1 (delta_ts U_tt^-T - sum_{m = 1, 2} U_t,t+m Z_t+m,s), which needs Z only on the
    frames t+1, t+2: a window of 2 x 2 blocks carried from the last frame up."""
    J, _, n = factors.shape
    F = n // 3
    padded = np.concatenate([factors, np.zeros((J, BAND + 1, 6))], -1)
    # U's blocks [J, F, m, 3, 3] between frame t and t + m (m = 0, 1, 2), read from the band storage.
    a, b, m = np.arange(3)[:, None, None], np.arange(3)[None, :, None], np.arange(3)[None, None, :]
    diagonal_offset = BAND + a - 3 * m - b  # the storage row of U[3t + a, 3(t + m) + b]
    inside = (diagonal_offset >= 0) & (diagonal_offset <= BAND)
    columns = 3 * np.arange(F)[:, None, None, None] + 3 * m + b  # [F, 3, 3, 3] (t, a, b, m)
    blocks = padded[:, np.clip(diagonal_offset, 0, BAND)[None], columns] * inside  # [J, F, a, b, m]
    blocks = np.moveaxis(blocks, -1, 2)  # [J, F, m, a, b]
    inverse = np.linalg.inv(blocks[:, :, 0])  # U_tt^-1
    out = np.zeros((J, F, 3, 3))
    window = np.zeros((J, 6, 6))  # Z over frames t+1, t+2
    for t in range(F - 1, -1, -1):
        coupling = np.concatenate([blocks[:, t, 1], blocks[:, t, 2]], -1)  # [J, 3, 6]: U_t,t+1 | U_t,t+2
        right = -inverse[:, t] @ coupling @ window  # Z_t,(t+1, t+2) [J, 3, 6]
        own = inverse[:, t] @ (inverse[:, t].swapaxes(-1, -2) - coupling @ right.swapaxes(-1, -2))
        own = 0.5 * (own + own.swapaxes(-1, -2))
        out[:, t] = own
        window = np.concatenate(
            [np.concatenate([own, right[..., :3]], -1), np.concatenate([right[..., :3].swapaxes(-1, -2), window[:, :3, :3]], -1)], 1
        )  # fmt: skip
    return out
