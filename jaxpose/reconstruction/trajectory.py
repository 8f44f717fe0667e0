"""A recording's motion solved over time: the per-instant evidence, a motion prior, constant limb lengths.

`jaxpose.reconstruction.fusion` estimates each instant alone: every joint's position y_tj with its
posterior covariance S_tj (`Fusion.covariance`), which already weighs the rays and the lifts.  Here the
whole recording's track x_tj (world mm) is the minimum of

    sum_tj  w_tj (x_tj - y_tj)^T S_tj^-1 (x_tj - y_tj)                 the evidence, robustly weighted
  + sum_tj  |x_t+1,j - 2 x_tj + x_t-1,j|^2 / q^2                       a constant-velocity prior
  + sum_tb  (|x_tc - x_tp| - L_b)^2 / limb_sigma^2                     each limb b = (c, p) of length L_b

- The motion prior: the acceleration (second difference) is white noise of `acceleration_mm_s2` per
  axis, q = acceleration_mm_s2 / fps^2 in mm per frame^2.  Where no evidence is (no camera sees the
  person), the minimum is the smoothest bridge between the ends, and its uncertainty grows toward the
  middle of the gap (a cubic spline's, not a straight line's held certainty).
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

Uncertainty (`Trajectory.sigma`): sqrt(trace) of each cell's marginal posterior covariance under each
joint's own system (the other joints held where they are), from the banded factor by the selected
inversion (Takahashi's recurrence), O(F) per joint.
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


@dataclasses.dataclass(frozen=True)
class TrajectoryConfig:
    """The trajectory's model (module docstring); chosen on the Human3.6M development split's training
    recordings (docs/reconstruction.md), not on the reported ones."""

    acceleration_mm_s2: float = 3000.0
    """The motion prior's process noise: a joint's acceleration, standard deviation per axis (mm/s^2)."""
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
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"TrajectoryConfig.{field.name} must be a positive number, got {value!r}")
        if not isinstance(self.iterations, int):
            raise ValueError(f"TrajectoryConfig.iterations must be a whole number, got {self.iterations!r}")


@dataclasses.dataclass(frozen=True)
class Trajectory:
    """A recording's track of F frames and J joints.

    points:       f32[F, J, 3] world mm at every frame (the bridge where there is no evidence; a joint
                  with fewer than `MIN_EVIDENCE_CELLS` cells of evidence: its input values).
    sigma:        f32[F, J] mm, the posterior RMS 3D error (module docstring); NaN where not solved.
    weight:       f32[F, J] each cell's final robust weight; 0 where it had no evidence.
    limb_lengths: f32[B] mm, the length each limb (`bones`' order) was held to; NaN where free.
    """

    points: np.ndarray
    sigma: np.ndarray
    weight: np.ndarray
    limb_lengths: np.ndarray


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


def solve_trajectory(
    points: np.ndarray,
    covariance: np.ndarray,
    provenance: np.ndarray,
    bones: Sequence[tuple[int, int]],
    fps: float,
    config: TrajectoryConfig = TrajectoryConfig(),
    lengths: np.ndarray | None = None,
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
    """
    points = np.asarray(points, np.float64)
    covariance = np.asarray(covariance, np.float64)
    F, J, _ = points.shape
    if points.shape[-1] != 3 or covariance.shape != (F, J, 3, 3) or np.shape(provenance) != (F, J):
        raise ValueError(
            f"solve_trajectory: points [F, J, 3], covariance [F, J, 3, 3] and provenance [F, J] expected, got"
            f" {points.shape}, {covariance.shape}, {np.shape(provenance)}"
        )
    if not fps > 0:
        raise ValueError(f"solve_trajectory: fps must be positive, got {fps}")
    has = np.isfinite(points).all(-1) & np.isfinite(covariance).all((-1, -2))
    scale = np.where(provenance == Provenance.LIFTED, config.lifted_sigma_scale**2, 1.0)
    precision = np.zeros((F, J, 3, 3))
    precision[has] = np.linalg.inv(covariance[has] * scale[has][:, None, None])
    observed = np.where(has[..., None], points, 0.0)
    solved = has.sum(0) >= MIN_EVIDENCE_CELLS  # [J]
    precision[:, ~solved] = np.eye(3)  # a dummy system for the joints left as they are, replaced below
    lengths = limb_lengths(points, provenance, bones) if lengths is None else np.asarray(lengths, np.float64)
    limbs = [(b, c, p) for b, (c, p) in enumerate(bones) if np.isfinite(lengths[b]) and solved[c] and solved[p]]
    system = _System(precision, observed, has, 1.0 / (config.acceleration_mm_s2 / fps**2) ** 2, 1.0 / config.limb_sigma_mm**2)

    dummy = np.broadcast_to(~solved, (F, J))  # held at 0 by unit weights, so that their systems stay regular
    weight = (has | dummy).astype(np.float64)
    track = system.solve(weight, limbs, lengths, None)
    for _ in range(config.iterations):
        residual = observed - track
        mahalanobis = np.sqrt(np.maximum(np.einsum("fja,fjab,fjb->fj", residual, precision, residual), 0.0))
        weight = np.where(dummy, 1.0, np.where(has, 1.0 / (1.0 + (mahalanobis / config.robust_sigmas) ** 2), 0.0))
        track = system.solve(weight, limbs, lengths, track)
    sigma = system.marginal_sigma(weight, limbs, track)
    track = np.where(solved[None, :, None], track, points)
    return Trajectory(
        track.astype(np.float32),
        np.where(solved[None], sigma, np.nan).astype(np.float32),
        np.where(has & solved[None], weight, 0.0).astype(np.float32),
        lengths.astype(np.float32),
    )


class _System:
    """The normal equations of the module docstring, for given robust weights and a linearisation of the
    limbs.  Unknowns x [F, J, 3] in the order (frame, joint, axis) as one vector of 3FJ."""

    def __init__(self, precision, observed, has, motion_weight: float, limb_weight: float):
        self.precision, self.observed, self.has = precision, observed, has
        self.motion_weight, self.limb_weight = motion_weight, limb_weight
        F, J = has.shape
        self.motion = scipy.sparse.csr_matrix((3 * F * J,) * 2)  # no second difference in fewer than 3 frames
        if F >= 3:
            second = scipy.sparse.diags([1.0, -2.0, 1.0], [0, 1, 2], shape=(F - 2, F))
            self.motion = scipy.sparse.kron(motion_weight * (second.T @ second), scipy.sparse.identity(3 * J), "csr")

    def _limb_rows(self, limbs, track) -> np.ndarray:
        """[L, F, 3]: sqrt(limb weight) u, u each limb's unit direction at `track` (0 where degenerate, and
        all 0 before there is a track): the linearised limb rows sqrt(w) u^T (x_c - x_p) = sqrt(w) L_b."""
        if track is None or not limbs:
            return np.zeros((len(limbs), len(self.has), 3))
        index = np.array(limbs)
        difference = track[:, index[:, 1]] - track[:, index[:, 2]]  # [F, L, 3]
        norm = np.linalg.norm(difference, axis=-1, keepdims=True)
        direction = np.where(norm > 1e-6, difference / np.maximum(norm, 1e-6), 0.0)
        return np.sqrt(self.limb_weight) * direction.swapaxes(0, 1)

    def _diagonal_blocks(self, weight, limbs, rows) -> np.ndarray:
        """[F, J, 3, 3]: each cell's own block: its weighted evidence and its limbs' u u^T."""
        blocks = weight[..., None, None] * self.precision
        for (_, child, parent), row in zip(limbs, rows):
            outer = row[:, :, None] * row[:, None, :]
            blocks[:, child] += outer
            blocks[:, parent] += outer
        return blocks

    def _matrix(self, blocks, limbs, rows) -> scipy.sparse.csr_matrix:
        """The whole normal matrix: the cells' blocks, the limbs' couplings -u u^T, the motion prior."""
        F, J = blocks.shape[:2]
        cell = np.arange(F * J).reshape(F, J)
        block_rows, block_columns, data = [cell.ravel()], [cell.ravel()], [blocks.reshape(-1, 3, 3)]
        for (_, child, parent), row in zip(limbs, rows):
            coupling = -(row[:, :, None] * row[:, None, :])
            block_rows += [cell[:, child], cell[:, parent]]
            block_columns += [cell[:, parent], cell[:, child]]
            data += [coupling, coupling]
        block_rows, block_columns, data = np.concatenate(block_rows), np.concatenate(block_columns), np.concatenate(data)
        axis = np.arange(3)
        rows_ = (3 * block_rows[:, None, None] + axis[None, :, None]).repeat(3, 2)
        columns = (3 * block_columns[:, None, None] + axis[None, None, :]).repeat(3, 1)
        evidence = scipy.sparse.coo_matrix((data.ravel(), (rows_.ravel(), columns.ravel())), shape=(3 * F * J,) * 2)
        return evidence.tocsr() + self.motion

    def solve(self, weight, limbs, lengths, track) -> np.ndarray:
        """[F, J, 3]: the minimum of the linearised problem (conjugate gradients, `_factors` preconditioning)."""
        rows = self._limb_rows(limbs, track)
        blocks = self._diagonal_blocks(weight, limbs, rows)
        rhs = np.einsum("fjab,fjb->fja", weight[..., None, None] * self.precision, self.observed)
        for (b, child, parent), row in zip(limbs, rows):
            rhs[:, child] += row * np.sqrt(self.limb_weight) * lengths[b]
            rhs[:, parent] -= row * np.sqrt(self.limb_weight) * lengths[b]
        matrix, factors = self._matrix(blocks, limbs, rows), self._factors(blocks)
        shape = rhs.shape

        def precondition(r):  # the joints' systems side by side: one banded matrix, joint-major
            solved = cho_solve_banded((factors, False), r.reshape(shape).swapaxes(0, 1).ravel(), check_finite=False)
            return solved.reshape(shape[1], shape[0], 3).swapaxes(0, 1).ravel()

        rhs = rhs.ravel()
        x = precondition(rhs) if track is None else track.ravel().copy()
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
        return x.reshape(shape)

    def _bands(self, blocks: np.ndarray) -> np.ndarray:
        """[J, BAND + 1, 3F]: each joint's system (its blocks and the motion prior) in LAPACK's upper band
        storage, ab[BAND + i - k, k] = A[i, k] for i <= k, unknowns in the order (frame, axis)."""
        F, J = blocks.shape[:2]
        ab = np.zeros((J, BAND + 1, 3 * F))
        for a in range(3):
            for b in range(a, 3):
                ab[:, BAND + a - b, b::3] = blocks[:, :, a, b].T
        # D^T D per axis: its diagonal and the two bands above it, 3 and 6 apart in the (frame, axis) order.
        diagonal, first, second = np.zeros(F), np.zeros(max(F - 1, 0)), np.zeros(max(F - 2, 0))
        if F >= 3:
            stencil = np.array([1.0, -2.0, 1.0])
            for i in range(3):
                diagonal[i : F - 2 + i] += stencil[i] ** 2
            for i in range(2):
                first[i : F - 2 + i] += stencil[i] * stencil[i + 1]
            second += stencil[0] * stencil[2]
        for a in range(3):
            ab[:, BAND, a::3] += self.motion_weight * diagonal
            ab[:, BAND - 3, 3 + a :: 3] += self.motion_weight * first
            ab[:, BAND - 6, 6 + a :: 3] += self.motion_weight * second
        return ab

    def _factors(self, blocks: np.ndarray) -> np.ndarray:
        """[BAND + 1, 3FJ]: the banded Cholesky factor of every joint's system, joint after joint (block
        diagonal: `_bands` leaves the entries above each joint's first rows 0, so one banded matrix holds all)."""
        bands = self._bands(blocks)
        return cholesky_banded(bands.swapaxes(0, 1).reshape(BAND + 1, -1), lower=False, check_finite=False)

    def marginal_sigma(self, weight, limbs, track) -> np.ndarray:
        """f64[F, J]: sqrt(trace) of each cell's marginal covariance under its joint's own system."""
        factors = self._factors(self._diagonal_blocks(weight, limbs, self._limb_rows(limbs, track)))
        factors = factors.reshape(BAND + 1, len(weight[0]), -1).swapaxes(0, 1)  # [J, BAND + 1, 3F]
        return np.sqrt(np.trace(_selected_blocks(factors), axis1=-2, axis2=-1)).T


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
