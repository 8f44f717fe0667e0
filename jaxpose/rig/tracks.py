"""Identity over time: the people of each instant (`jaxpose.rig.association`) joined into tracks.

Each track keeps its last centre (the median of its joints, world), a velocity (an average over its
recent steps) and its limb lengths.  At each instant the tracks and the instant's people are paired by the
Hungarian assignment (`scipy.optimize.linear_sum_assignment`) on the distance from where a track's
centre and velocity put it to each person's centre.  A pair further apart than the gate is refused; the
gate is `gate_mm` a step, widening by `speed_mm_s` for each second a track has not been seen (it may have
walked off): a track survives occlusions and the person leaving and coming back near where they left.
Two people passing each other keep their identities while their centres stay further apart than the
distance each moves between instants: the prediction puts each track ahead of itself, not onto the other.

A person paired with no track starts a new one; with `people` set (the user knows how many there are),
no more tracks than that are started, and a person beyond them is given to the unseen track whose limb
lengths are closest (someone coming back far from where they left), or left out.  Tracks seen at fewer
than `min_instants` instants are dropped (false people that happened to agree across views) and counted.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
from scipy.optimize import linear_sum_assignment


PREDICTION_STEPS = 10  # instants a velocity is carried forward: further, a person has turned or stopped


@dataclasses.dataclass(frozen=True)
class TrackSettings:
    """The parameters of the module docstring, world units in mm."""

    fps: float = 25.0
    gate_mm: float = 500.0
    """Largest distance, in one step, of a person's centre from its track's prediction."""
    speed_mm_s: float = 2000.0
    """How much further, per second unseen, a track may have gone (a brisk walk)."""
    max_gate_mm: float = 3000.0
    min_instants: int = 10
    people: int | None = None
    """The number of people, when the user knows it (``--people N``)."""


@dataclasses.dataclass(frozen=True)
class Tracks:
    """Each person of each instant's track."""

    identity: np.ndarray
    """int32[n, M]: the track (0, 1, ... in order of first appearance) of each slot, -1 where none."""
    count: int
    """How many tracks."""
    dropped: int
    """Person-instants left out: in tracks shorter than `min_instants`, or beyond `people`."""


def centres(points: np.ndarray) -> np.ndarray:
    """f32[..., J, 3] -> the median of the joints seen, NaN where none is."""
    with warnings.catch_warnings():  # an all-NaN person is NaN, said by the result
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmedian(points, axis=-2)


def limb_lengths(points: np.ndarray, limbs: np.ndarray) -> np.ndarray:
    """f32[..., J, 3], int[L, 2] -> f32[..., L] (NaN where an end is missing)."""
    return np.linalg.norm(points[..., limbs[:, 0], :] - points[..., limbs[:, 1], :], axis=-1)


def follow(points: np.ndarray, present: np.ndarray, limbs: np.ndarray, settings: TrackSettings = TrackSettings()) -> Tracks:
    """Tracks of the people `points` f32[n, M, J, 3] (world mm) where `present` bool[n, M]; `limbs` int[L, 2]
    the skeleton's limbs (compared when someone comes back, see the module docstring)."""
    n, M = present.shape
    centre = centres(points)  # [n, M, 3]
    present = present & np.isfinite(centre).all(-1)
    lengths = limb_lengths(points, limbs)
    step = 1.0 / settings.fps
    last, velocity, seen_at, limb_sum, limb_count = [], [], [], [], []
    raw = np.full((n, M), -1, np.int64)
    for i in range(n):
        slots = np.flatnonzero(present[i])
        if not len(slots):
            continue
        T = len(last)
        assigned = np.full(len(slots), -1)
        if T:
            gap = i - np.array(seen_at)
            predicted = np.array(last) + np.array(velocity) * np.minimum(gap, PREDICTION_STEPS)[:, None]
            gate = np.minimum(settings.gate_mm + settings.speed_mm_s * step * (gap - 1), settings.max_gate_mm)
            cost = np.linalg.norm(predicted[:, None] - centre[i, slots][None], axis=-1)  # [T, S]
            rows, cols = linear_sum_assignment(np.where(cost <= gate[:, None], cost, 1e9))
            keep = cost[rows, cols] <= gate[rows]
            assigned[cols[keep]] = rows[keep]
        for s in np.flatnonzero(assigned < 0):
            if settings.people is None or len(last) < settings.people:
                assigned[s] = len(last)
                last.append(centre[i, slots[s]])
                velocity.append(np.zeros(3))
                seen_at.append(i)
                limb_sum.append(np.zeros(len(limbs)))
                limb_count.append(np.zeros(len(limbs)))
                continue
            unseen = [t for t in range(len(last)) if seen_at[t] < i and t not in assigned]
            if unseen:
                means = np.array([limb_sum[t] / np.maximum(limb_count[t], 1) for t in unseen])
                difference = np.nanmean(np.abs(means - lengths[i, slots[s]]), axis=-1)
                assigned[s] = unseen[int(np.nanargmin(np.nan_to_num(difference, nan=np.inf)))]
                velocity[assigned[s]] = np.zeros(3)
        for s, t in zip(slots, assigned):
            if t < 0:
                continue
            gap = i - seen_at[t]
            if gap:
                moved = (centre[i, s] - last[t]) / gap
                velocity[t] = moved if not velocity[t].any() else 0.5 * velocity[t] + 0.5 * moved
            last[t], seen_at[t] = centre[i, s], i
            finite = np.isfinite(lengths[i, s])
            limb_sum[t][finite] += lengths[i, s][finite]
            limb_count[t][finite] += 1
            raw[i, s] = t
    sizes = np.bincount(raw[raw >= 0], minlength=len(last))
    kept = np.flatnonzero(sizes >= settings.min_instants)
    renumber = np.full(len(last) + 1, -1)
    renumber[kept] = np.arange(len(kept))  # tracks start in order, so this keeps the order of first appearance
    identity = renumber[raw].astype(np.int32)
    return Tracks(identity, len(kept), int((present & (identity < 0)).sum()))


def track_points(points: np.ndarray, identity: np.ndarray, count: int, max_gap: int) -> np.ndarray:
    """Each track's joints at every instant: points f32[n, M, J, 3], identity int[n, M] -> f32[n, count, J, 3];
    a joint unseen for at most `max_gap` instants between two sightings is interpolated linearly (an
    occlusion, a view's miss), NaN elsewhere."""
    n, M, J, _ = points.shape
    out = np.full((n, count, J, 3), np.nan, np.float32)
    instants, slots = np.nonzero(identity >= 0)
    out[instants, identity[instants, slots]] = points[instants, slots]
    seen = np.isfinite(out).all(-1)  # [n, T, J]
    steps = np.arange(n)
    for t in range(count):
        for j in range(J):
            known = np.flatnonzero(seen[:, t, j])
            if len(known) < 2:
                continue
            gaps = np.diff(known)
            fill = np.flatnonzero((gaps > 1) & (gaps <= max_gap + 1))
            for g in fill:
                inside = steps[known[g] + 1 : known[g + 1]]
                share = ((inside - known[g]) / gaps[g])[:, None]
                out[inside, t, j] = (1 - share) * out[known[g], t, j] + share * out[known[g + 1], t, j]
    return out
