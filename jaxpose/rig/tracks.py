"""Identity over time: the people of each instant (`jaxpose.rig.association`) joined into tracks.

Each track keeps its joints where last seen (world), a velocity (an average over its recent steps, no
faster than `speed_mm_s`) and its limb lengths.  At each instant the tracks and the instant's people are
paired by the Hungarian assignment (`scipy.optimize.linear_sum_assignment`) on the distance from where a
track's joints and velocity put it to each person: the median over the joints both have of the joints'
distances (a person whose legs are hidden is not moved up by half a body).  A pair further apart than the
gate is refused; the gate is `gate_mm` a step, widening by `speed_mm_s` for each second a track has not
been seen.  Two people passing each other keep their identities while they stay further apart than the
distance each moves between instants: the prediction puts each track ahead of itself, not onto the other.

A person paired with no track starts a tentative one.  It becomes a person (confirmed) once seen at
`min_instants` instants without a gap of more than `lost_after`; before that, a longer gap ends it, its
instants dropped and counted: a false person that happens to agree across views now and then never lasts.
A confirmed track unseen for more than `lost_after` instants is lost: it takes part in no pairing until a
tentative track is confirmed and turns out to be it (so a false person near where someone left never takes
their identity).  On confirmation, the lost people unseen since before the tentative track began are
candidates: those within the gate (grown with the time unseen) of where the tentative track began, the
nearest (in gates); else, someone coming back far from where they left, a lost person whose
limb lengths differ from its by at most `reidentify_mm` (the mean over limbs), the closest.  The track then
continues theirs, from the tentative track's first instant.  With `people` set (the user knows how many
there are), no more than that are confirmed: beyond them a tentative track continues the lost person whose
limb lengths are closest, whatever the difference, or ends when nobody is lost.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.optimize import linear_sum_assignment

from jaxpose.rig import people


PREDICTION_STEPS = 10  # instants a velocity is carried forward: further, a person has turned or stopped


@dataclasses.dataclass(frozen=True)
class TrackSettings:
    """The parameters of the module docstring, world units in mm."""

    fps: float = 25.0
    gate_mm: float = 500.0
    """Largest distance, in one step, of a person from its track's prediction (median over joints)."""
    speed_mm_s: float = 2000.0
    """How much further, per second unseen, a track may have gone (a brisk walk)."""
    max_gate_mm: float = 3000.0
    min_instants: int = 10
    """Instants a tentative track must be seen at to be a person."""
    lost_after: int = 5
    """Instants unseen after which a tentative track ends and a confirmed one is lost."""
    reidentify_mm: float = 25.0
    """Largest mean limb-length difference of a new person from an unseen one for it to be them coming back."""
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
    """Person-instants left out: in tentative tracks that ended, or beyond `people`."""


def limb_lengths(points: np.ndarray, limbs: np.ndarray) -> np.ndarray:
    """f32[..., J, 3], int[L, 2] -> f32[..., L] (NaN where an end is missing)."""
    return np.linalg.norm(points[..., limbs[:, 0], :] - points[..., limbs[:, 1], :], axis=-1)


@dataclasses.dataclass
class _Track:
    """One track's state while `follow` runs (mutable: it changes at every instant it is seen)."""

    first: int
    start: np.ndarray  # f[J, 3] joints at the first instant, world mm (NaN: unseen)
    last: np.ndarray  # f[J, 3] each joint where last seen, world mm
    seen_at: int
    limb_sum: np.ndarray
    limb_count: np.ndarray
    velocity: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))
    sightings: int = 1
    confirmed: bool = False
    continues: int = -1  # the confirmed track this one turned out to be (someone coming back), -1: none
    ended: bool = False

    def limbs(self) -> np.ndarray:
        return np.where(self.limb_count > 0, self.limb_sum / np.maximum(self.limb_count, 1), np.nan)


def _limb_difference(a: np.ndarray, b: np.ndarray) -> float:
    both = np.isfinite(a) & np.isfinite(b)
    return float(np.mean(np.abs(a[both] - b[both]))) if both.any() else np.inf


def _gate(settings: TrackSettings, gap: np.ndarray) -> np.ndarray:
    """How far (mm) a person may be from its track's prediction after `gap` instants (1: seen at the last)."""
    return np.minimum(settings.gate_mm + settings.speed_mm_s / settings.fps * (gap - 1), settings.max_gate_mm)


def _predicted(track: _Track, instant: int) -> np.ndarray:
    return track.last + track.velocity * min(instant - track.seen_at, PREDICTION_STEPS)


def _distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """f[..., J, 3] twice -> the median over the joints both have of their distances (inf: none shared)."""
    return np.nan_to_num(people._median_over_last(np.linalg.norm(a - b, axis=-1)), nan=np.inf)


def _confirm(tracks: list[_Track], t: int, settings: TrackSettings) -> None:
    """Track t has been seen at `min_instants` instants: a person, new or coming back (module docstring)."""
    track = tracks[t]
    confirmed = [u for u, other in enumerate(tracks) if other.confirmed and other.continues < 0]
    lost = [u for u in confirmed if tracks[u].seen_at < track.first]
    difference = {u: _limb_difference(tracks[u].limbs(), track.limbs()) for u in lost}
    # how far, in gates, where the tentative track began is from where each lost person would be
    away = {u: _distance(track.start, _predicted(tracks[u], track.first)) / _gate(settings, track.first - tracks[u].seen_at) for u in lost}
    near = [u for u in lost if away[u] <= 1.0]
    alike = [u for u in lost if difference[u] <= settings.reidentify_mm]
    full = settings.people is not None and len(confirmed) >= settings.people
    if near or alike or (full and lost):
        u = min(near, key=away.get) if near else min(alike or lost, key=difference.get)
        old = tracks[u]
        old.last, old.seen_at, old.velocity = track.last, track.seen_at, track.velocity
        old.limb_sum, old.limb_count = old.limb_sum + track.limb_sum, old.limb_count + track.limb_count
        track.continues, track.confirmed = u, True
    elif full:
        track.ended = True
    else:
        track.confirmed = True


def follow(points: np.ndarray, present: np.ndarray, limbs: np.ndarray, settings: TrackSettings = TrackSettings()) -> Tracks:
    """Tracks of the people `points` f32[n, M, J, 3] (world mm) where `present` bool[n, M]; `limbs` int[L, 2]
    the skeleton's limbs (compared when someone comes back, see the module docstring)."""
    n, M = present.shape
    present = present & np.isfinite(points).all(-1).any(-1)
    fastest = settings.speed_mm_s / settings.fps  # mm an instant
    lengths = limb_lengths(points, limbs)
    found: list[_Track] = []
    raw = np.full((n, M), -1, np.int64)
    for i in range(n):
        for track in found:  # a tentative track unseen too long ends
            if not track.confirmed and not track.ended and i - track.seen_at > settings.lost_after + 1:
                track.ended = True
        live = [t for t, track in enumerate(found) if not track.ended and track.continues < 0 and i - track.seen_at <= settings.lost_after + 1]
        slots = np.flatnonzero(present[i])
        if not len(slots):
            continue
        assigned = np.full(len(slots), -1)
        if live:
            gate = _gate(settings, i - np.array([found[t].seen_at for t in live]))
            predicted = np.array([_predicted(found[t], i) for t in live])
            cost = _distance(predicted[:, None], points[i, slots][None])  # [T, S]
            rows, cols = linear_sum_assignment(np.where(cost <= gate[:, None], cost, 1e9))
            keep = cost[rows, cols] <= gate[rows]
            assigned[cols[keep]] = np.array(live)[rows[keep]]
        for s in np.flatnonzero(assigned < 0):
            assigned[s] = len(found)
            found.append(_Track(i, points[i, slots[s]].copy(), points[i, slots[s]].copy(), i, np.zeros(len(limbs)), np.zeros(len(limbs)), sightings=0))
        for s, t in zip(slots, assigned):
            track = found[t]
            gap = i - track.seen_at
            seen = np.isfinite(points[i, s]).all(-1)
            if gap:
                both = seen & np.isfinite(track.last).all(-1)
                if both.any():
                    moved = np.median(points[i, s][both] - track.last[both], axis=0) / gap
                    velocity = moved if not track.velocity.any() else 0.5 * track.velocity + 0.5 * moved
                    track.velocity = velocity * min(1.0, fastest / max(float(np.linalg.norm(velocity)), 1e-9))
                track.sightings += 1
            elif track.sightings == 0:
                track.sightings = 1
            track.last[seen], track.seen_at = points[i, s][seen], i
            finite = np.isfinite(lengths[i, s])
            track.limb_sum[finite] += lengths[i, s][finite]
            track.limb_count[finite] += 1
            raw[i, s] = t
            if not track.confirmed and track.sightings >= settings.min_instants:
                _confirm(found, t, settings)
    identity_of = np.full(len(found) + 1, -1)  # the last entry: raw's -1
    order = []
    for t, track in enumerate(found):
        if track.confirmed and track.continues < 0:
            order.append(t)
    identity_of[order] = np.arange(len(order))  # tracks start in order, so this keeps the order of first appearance
    for t, track in enumerate(found):
        if track.continues >= 0:
            identity_of[t] = identity_of[track.continues]
    identity = identity_of[raw].astype(np.int32)
    return Tracks(identity, len(order), int((present & (identity < 0)).sum()))


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
