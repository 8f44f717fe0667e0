"""The scores of `benchmarks/peers.py`, per method over a project's recordings.

World MPJPE (mm, no alignment) on all joints and on those whose definitions agree with the ground
truth's; P-MPJPE (Procrustes per instant, `jaxpose.metrics.p_mpjpe`) on the instants a method gives
every joint; the acceleration error (mm/frame^2: the second difference against the ground truth's, on
joints and instants whose neighbours both have); each limb's length spread over time (standard
deviation, mm); coverage and MPJPE by the number of views that detected the joint; the instants some
camera sees that have a gap.  And the world error split in two: per recording and joint, its mean error
vector over the covered instants (the offset: a joint the detector defines otherwise than the ground
truth, which no model of motion removes), and what varies about it; each as a mean over the cells.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from jaxpose.metrics import p_mpjpe

BUCKETS = ("0", "1", "2", "3+")


def acceleration_error(points: np.ndarray, truth: np.ndarray) -> tuple[float, int]:
    """(sum, count) of |a - a_truth| (mm/frame^2) over joints and instants whose neighbours the method
    and the truth both have; a = x[t+1] - 2 x[t] + x[t-1]."""
    second = lambda x: x[2:] - 2 * x[1:-1] + x[:-2]  # noqa: E731
    error = np.linalg.norm(second(points) - second(truth), axis=-1)
    known = np.isfinite(error)
    return float(error[known].sum()), int(known.sum())


def limb_spread(points: np.ndarray, limbs: Sequence[tuple[int, int]]) -> np.ndarray:
    """f64[L]: each limb's length's standard deviation over the instants that have both ends (NaN below 2)."""
    spreads = []
    for a, b in limbs:
        length = np.linalg.norm(points[:, a] - points[:, b], axis=-1)
        length = length[np.isfinite(length)]
        spreads.append(float(length.std()) if len(length) >= 2 else np.nan)
    return np.array(spreads)


class Scores:
    """One method's sums over recordings (module docstring)."""

    def __init__(self, agreeing: np.ndarray):
        self.agreeing = agreeing  # bool[J]
        names = ("error", "cells", "covered", "agreeing_error", "agreeing_covered", "pa", "pa_frames", "accel", "accel_count", "gaps",
                 "seen", "offset", "about_offset")  # fmt: skip
        self.sums = dict.fromkeys(names, 0.0)
        self.bucket = {name: np.zeros(len(BUCKETS)) for name in ("cells", "covered", "error")}
        self.spreads: list[np.ndarray] = []

    def add(self, points: np.ndarray, truth: np.ndarray, views: np.ndarray, seen: np.ndarray, limbs) -> None:
        error = np.linalg.norm(points - truth, axis=-1)  # [F, J]
        labelled = np.isfinite(truth).all(-1)
        covered = labelled & np.isfinite(error)
        s = self.sums
        s["cells"] += labelled.sum()
        s["covered"] += covered.sum()
        s["error"] += error[covered].sum()
        s["agreeing_covered"] += covered[:, self.agreeing].sum()
        s["agreeing_error"] += error[:, self.agreeing][covered[:, self.agreeing]].sum()
        difference = np.where(covered[..., None], points - truth, 0.0)
        offset = difference.sum(0) / np.maximum(covered.sum(0), 1)[:, None]  # [J, 3] per joint over the recording
        s["offset"] += np.sum(covered.sum(0) * np.linalg.norm(offset, axis=-1))
        s["about_offset"] += np.linalg.norm(difference - offset, axis=-1)[covered].sum()
        complete = covered.all(-1)
        if complete.any():
            s["pa"] += float(np.asarray(p_mpjpe(points[complete], truth[complete])).sum())
            s["pa_frames"] += complete.sum()
        total, count = acceleration_error(points, truth)
        s["accel"] += total
        s["accel_count"] += count
        s["gaps"] += (seen & ~np.isfinite(points).all((-1, -2))).sum()
        s["seen"] += seen.sum()
        bucket = np.minimum(views, 3)
        for b in range(len(BUCKETS)):
            cells = labelled & (bucket == b)
            self.bucket["cells"][b] += cells.sum()
            self.bucket["covered"][b] += (cells & covered).sum()
            self.bucket["error"][b] += error[cells & covered].sum()
        self.spreads.append(limb_spread(points, limbs))

    def summary(self) -> dict:
        s = self.sums
        ratio = lambda a, b: float(a / b) if b else None  # noqa: E731
        return {
            "mpjpe_mm": ratio(s["error"], s["covered"]),
            "covered_pct": ratio(100 * s["covered"], s["cells"]),
            "mpjpe_agreeing_mm": ratio(s["agreeing_error"], s["agreeing_covered"]),
            "p_mpjpe_mm": ratio(s["pa"], s["pa_frames"]),
            "complete_frames": int(s["pa_frames"]),
            "accel_error_mm_per_frame2": ratio(s["accel"], s["accel_count"]),
            "limb_spread_mm": float(np.nanmean(np.stack(self.spreads))) if self.spreads else None,
            "offset_mm": ratio(s["offset"], s["covered"]),
            "about_offset_mm": ratio(s["about_offset"], s["covered"]),
            "instants_with_a_gap": int(s["gaps"]),
            "instants_seen": int(s["seen"]),
            "buckets": {
                label: {
                    "cells": int(self.bucket["cells"][b]),
                    "covered_pct": ratio(100 * self.bucket["covered"][b], self.bucket["cells"][b]),
                    "mpjpe_mm": ratio(self.bucket["error"][b], self.bucket["covered"][b]),
                }
                for b, label in enumerate(BUCKETS)
            },
        }
