"""How a reconstructed motion moves: its jitter, its limbs' length over time, and against ground truth.

- Acceleration: the second difference x_t+1 - 2 x_t + x_t-1 (mm/frame^2), its norm averaged over the
  cells (frame x joint) where the three frames have the joint.  A per-instant estimate's noise shows
  here first: white noise of sigma per axis gives sqrt(6) sigma per axis, a mean norm of about 3.9 sigma.
- Acceleration error: the norm of the difference between the motion's and the ground truth's second
  differences, averaged over the cells where both have the three frames (the usual "accel error" of
  video pose estimation).
- Limb length spread: each limb's standard deviation over time (mm), over the frames with both joints.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def second_differences(points: np.ndarray) -> np.ndarray:
    """f64[F - 2, J, 3] the second differences of [F, J, 3] (mm/frame^2); NaN where a frame lacks the joint."""
    points = np.asarray(points, np.float64)
    return points[2:] - 2.0 * points[1:-1] + points[:-2]


def mean_acceleration(points: np.ndarray) -> float | None:
    """The mean norm of the second differences (mm/frame^2); None where no cell has three frames."""
    norms = np.linalg.norm(second_differences(points), axis=-1)
    return float(np.nanmean(norms)) if np.isfinite(norms).any() else None


def acceleration_error(points: np.ndarray, truth: np.ndarray) -> tuple[float, int]:
    """(the summed norm of the difference of second differences, the cells it sums): mm/frame^2 once divided."""
    error = np.linalg.norm(second_differences(points) - second_differences(truth), axis=-1)
    counted = np.isfinite(error)
    return float(error[counted].sum()), int(counted.sum())


def limb_length_spread(points: np.ndarray, bones: Sequence[tuple[int, int]]) -> np.ndarray:
    """f64[B]: each limb's (child, parent) length's standard deviation over the frames with both joints
    (mm); NaN for a limb with fewer than two such frames."""
    points = np.asarray(points, np.float64)
    out = np.full(len(bones), np.nan)
    for b, (child, parent) in enumerate(bones):
        lengths = np.linalg.norm(points[:, child] - points[:, parent], axis=-1)
        lengths = lengths[np.isfinite(lengths)]
        if len(lengths) >= 2:
            out[b] = lengths.std()
    return out


def motion_summary(points: np.ndarray, bones: Sequence[tuple[int, int]], joint_names: Sequence[str], truth: np.ndarray | None = None) -> dict:
    """One recording's motion for a report: mean acceleration (mm/frame^2), each limb's length spread
    (std, mm, named "parent-child") and their mean, and with `truth` ([F, J, 3], NaN where none) the
    acceleration error (mm/frame^2)."""
    spread = limb_length_spread(points, bones)
    summary = {
        "mean_acceleration_mm_per_frame2": mean_acceleration(points),
        "limb_length_std_mm": {
            f"{joint_names[parent]}-{joint_names[child]}": None if np.isnan(value) else float(value)
            for (child, parent), value in zip(bones, spread)
        },
        "mean_limb_length_std_mm": float(np.nanmean(spread)) if np.isfinite(spread).any() else None,
    }
    if truth is not None:
        total, count = acceleration_error(points, truth)
        summary["acceleration_error_mm_per_frame2"] = total / count if count else None
    return summary
