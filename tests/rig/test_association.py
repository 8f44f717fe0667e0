"""Several people: association across views (`jaxpose.rig.association`) and tracks over time
(`jaxpose.rig.tracks`) on synthetic scenes whose truth is known: copies of one body placed in the
example project's rig, projected exactly, each view's detections shuffled."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxpose.rig import association, tracks
from jaxpose.skeleton import H36M_17
from jaxpose.synthetic.capture import rig_calibration

LIMBS = np.array([(j, p) for j, p in enumerate(H36M_17.parents) if p >= 0])


def _rig():
    cameras = rig_calibration().cameras
    return np.einsum("cij,cjk->cik", cameras.K, np.concatenate([cameras.R, cameras.t[:, :, None]], -1)).astype(np.float32)


P = _rig()
C = len(P)
# A standing body, mm: 17 joints within a 0.5 x 0.3 x 1.7 m box, feet on the floor (z up).
BODY = np.random.default_rng(7).uniform((-250, -150, 0), (250, 150, 1700), (17, 3)).astype(np.float32)


def project(points):
    """f32[..., J, 3] -> f32[..., C, J, 2] pixels in every view."""
    homogeneous = np.concatenate([points, np.ones((*points.shape[:-1], 1), np.float32)], -1)
    x = np.einsum("cik,...jk->...cji", P, homogeneous)
    return x[..., :2] / x[..., 2:]


def scene(centres, rng, noise_px=1.0, false_per_view=0, hidden=()):
    """One instant: people at `centres` [M, 2] (floor, mm), each view's detections shuffled, with
    `false_per_view` false people per view and person m unseen in the views `hidden` lists as (m, view).
    -> keypoints [1, C, K, J, 2], confidence [1, C, K, J], truth int[M, C] (the detection of each person, -1)."""
    people = BODY[None] + np.concatenate([centres, np.zeros((len(centres), 1))], -1)[:, None].astype(np.float32)
    pixels = project(people) + rng.normal(0, noise_px, (len(centres), C, 17, 2))  # [M, C, J, 2]
    views = [[(m, pixels[m, c]) for m in range(len(centres)) if (m, c) not in hidden] for c in range(C)]
    for c in range(C):
        for _ in range(false_per_view):
            # a pose-like false detection: a person's projection turned 30-150 degrees in the image, moved
            xy = pixels[rng.integers(len(centres)), c]
            turn = np.deg2rad(rng.uniform(30, 150)) * rng.choice([-1, 1])
            rotation = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
            views[c].append((-1, (xy - xy.mean(0)) @ rotation.T + xy.mean(0) + rng.uniform(-300, 300, 2)))
    K = max(len(v) for v in views)
    keypoints = np.zeros((1, C, K, 17, 2), np.float32)
    confidence = np.zeros((1, C, K, 17), np.float32)
    truth = np.full((len(centres), C), -1)
    for c, detections in enumerate(views):
        for k, index in enumerate(rng.permutation(len(detections))):
            m, xy = detections[index]
            keypoints[0, c, k], confidence[0, c, k] = xy, 0.9
            if m >= 0:
                truth[m, c] = k
    return keypoints, confidence, truth, people


def groups(found):
    return {tuple(row) for row in found.detection[0][found.present[0]].tolist()}


@settings(max_examples=15, deadline=None)
@given(st.integers(2, 5), st.integers(0, 3), st.integers(0, 2**31 - 1))
def test_association_recovers_every_person(people, false, seed):
    """Oracle: every person seen by two views or more is found with exactly its detections; no real detection
    of theirs is in any other group (two false detections, or a false one and the person seen by one view
    only, may agree in two views: tracks drop such brief people); everything else is counted unmatched."""
    rng = np.random.default_rng(seed)
    angle = np.linspace(0, 2 * np.pi, people, endpoint=False) + rng.uniform(0, 1)
    centres = 1200 * np.stack([np.cos(angle), np.sin(angle)], -1)
    single = (people - 1, [c for c in range(C) if c != 0])  # the last person in view 0 only
    keypoints, confidence, truth, bodies = scene(centres, rng, false_per_view=false, hidden=[(single[0], c) for c in single[1]])
    found = association.associate(P, keypoints, confidence, threshold_px=20.0)
    real = {tuple(row) for row in truth[:-1].tolist()}
    assert real <= groups(found)
    extra = groups(found) - real
    taken = {(c, k) for row in real for c, k in enumerate(row) if k >= 0}
    assert not any((c, k) in taken for row in extra for c, k in enumerate(row) if k >= 0)
    assert found.unmatched == false * C + 1 - sum(k >= 0 for row in extra for k in row)
    slot = {tuple(row): m for m, row in enumerate(truth.tolist())}
    for row, points in zip(found.detection[0][found.present[0]].tolist(), found.points[0][found.present[0]]):
        if tuple(row) in real:
            assert np.median(np.linalg.norm(points - bodies[slot[tuple(row)]], axis=-1)) < 30.0  # mm, at 1 px noise


def test_people_close_together_stay_apart():
    """Two people 0.5 m apart (centre to centre): two persons, each with its own detections."""
    rng = np.random.default_rng(1)
    keypoints, confidence, truth, _ = scene(np.array([[0.0, 0.0], [500.0, 0.0]]), rng)
    found = association.associate(P, keypoints, confidence, threshold_px=20.0)
    assert groups(found) == {tuple(row) for row in truth.tolist()}


def test_hostile_instants():
    """50 false detections in a view, people with every joint missing, nobody at all: no error, all counted
    (three of the rig's views: the proposals grow as views^2 detections^2)."""
    rng = np.random.default_rng(2)
    keypoints, confidence, truth, _ = scene(np.array([[0.0, 0.0], [1500.0, 500.0]]), rng)
    crowd = np.zeros((1, 3, 52, 17, 2), np.float32)
    weight = np.zeros((1, 3, 52, 17), np.float32)
    crowd[:, :, :2], weight[:, :, :2] = keypoints[:, :3], confidence[:, :3]
    crowd[0, 0, 2:] = rng.uniform(0, 1000, (50, 17, 2))
    weight[0, 0, 2:] = 0.5
    weight[0, 1, 0] = 0  # a person with every joint missing in view 1
    found = association.associate(P[:3], crowd, weight, threshold_px=20.0)
    assert len(groups(found)) == 2 and found.unmatched <= 50
    empty = association.associate(P, np.zeros((3, C, 2, 17, 2), np.float32), np.zeros((3, C, 2, 17), np.float32))
    assert not empty.present.any() and empty.unmatched == 0


def walk(n, start, end):
    return start + (end - start) * np.linspace(0, 1, n)[:, None]


def test_tracks_no_swap_when_passing_at_half_a_metre():
    """Two people walk past each other 0.5 m apart (1.4 m/s, 25 fps), one is occluded for 20 instants and
    one leaves for 40 instants; the identities stay, in order of first appearance."""
    n = 150
    a = walk(n, np.array([-3000.0, 0.0]), np.array([3000.0, 0.0]))
    b = walk(n, np.array([3000.0, 500.0]), np.array([-3000.0, 500.0]))
    points = np.full((n, 2, 17, 3), np.nan, np.float32)
    points[:, 0] = BODY + np.concatenate([a, np.zeros((n, 1))], -1)[:, None]
    points[:, 1] = BODY + np.concatenate([b, np.zeros((n, 1))], -1)[:, None]
    present = np.ones((n, 2), bool)
    present[60:80, 0] = False  # occluded while passing
    present[100:140, 1] = False  # away
    points[~present] = np.nan
    rng = np.random.default_rng(0)
    order = rng.random(n) < 0.5  # the slots in random order
    points[order] = points[order][:, ::-1]
    present[order] = present[order][:, ::-1]
    followed = tracks.follow(points, present, LIMBS, tracks.TrackSettings(fps=25.0))
    truth = np.where(order[:, None], [[1, 0]], [[0, 1]])
    assert followed.count == 2 and followed.dropped == 0
    assert (followed.identity[present] == truth[present]).all()


def test_tracks_drop_brief_false_people_and_keep_the_count():
    n = 60
    points = np.full((n, 3, 17, 3), np.nan, np.float32)
    points[:, 0] = BODY
    points[:, 1] = BODY + np.array([2000.0, 0, 0], np.float32)
    present = np.zeros((n, 3), bool)
    present[:, :2] = True
    present[10:13, 2] = True  # a false person for three instants
    points[10:13, 2] = BODY + np.array([-2500.0, 1000.0, 0], np.float32)
    followed = tracks.follow(points, present, LIMBS)
    assert followed.count == 2 and followed.dropped == 3
    assert (followed.identity[:, :2] == [0, 1]).all() and (followed.identity[:, 2] == -1).all()
    # --people 2: the third is never a track, whatever its length
    present[10:40, 2] = True
    points[10:40, 2] = BODY + np.array([-2500.0, 1000.0, 0], np.float32)
    assert tracks.follow(points, present, LIMBS, tracks.TrackSettings(people=2)).count == 2


def test_track_points_fill_short_gaps_only():
    points = np.zeros((30, 1, 2, 3), np.float32) + np.arange(30, dtype=np.float32)[:, None, None, None]
    identity = np.zeros((30, 1), np.int32)
    identity[5:8] = -1  # 3 instants: filled
    identity[15:27] = -1  # 12 instants: left empty at max_gap 10
    out = tracks.track_points(points, identity, 1, max_gap=10)
    np.testing.assert_allclose(out[5:8, 0, :, 0], np.arange(5, 8)[:, None].repeat(2, 1))
    assert np.isnan(out[15:27]).all() and np.isfinite(out[:15]).all() and np.isfinite(out[27:]).all()


def stack(instants):
    """Instants of `scene` (keypoints, confidence, truth, ...) -> keypoints [n, C, K, J, 2], confidence
    [n, C, K, J] padded with nobody to the most detections of any view, and each instant's truth."""
    K = max(keypoints.shape[2] for keypoints, *_ in instants)
    pad = lambda array: np.pad(array, [(0, 0), (0, 0), (0, K - array.shape[2])] + [(0, 0)] * (array.ndim - 3))  # noqa: E731
    keypoints = np.concatenate([pad(keypoints) for keypoints, *_ in instants])
    confidence = np.concatenate([pad(confidence) for _, confidence, *_ in instants])
    return keypoints, confidence, [truth for _, _, truth, _ in instants]


@pytest.mark.slow  # ~40-80 s on 2 cores: 80 instants padded to the crowd's 54 detections per view
def test_hostile_sequence_count_changing_every_instant():
    """Four people, 1 to 4 of them in view at each instant (the count changes every instant), an instant with
    50 false detections in one view, a person with every joint missing in a view, a fifth person seen by one
    view only for 20 instants: every real person found with exactly its detections, one identity each from
    the first instant to the last, nothing lost (every detection with a joint seen is in a person or counted
    unmatched), no track for the one-view person or the crowd."""
    rng = np.random.default_rng(5)
    n = 80
    home = np.array([[-1500.0, -1500.0], [1500.0, -1500.0], [1500.0, 1500.0], [-1500.0, 1500.0], [0.0, 0.0]])
    instants, who = [], []
    for i in range(n):
        here = [m for m in range(4) if m < 1 + (i + m) % 4] if i % 2 else [m for m in range(4) if m >= 3 - i % 4]
        centres = home[here] + [[10.0 * i, 5.0 * i]]
        hidden = []
        if 30 <= i < 50:  # a fifth person, in view 2 only
            centres = np.concatenate([centres, home[4:]])
            hidden = [(len(here), c) for c in range(C) if c != 2]
        instant = list(scene(centres, rng, hidden=hidden))
        if i == 40:  # 50 false detections in view 0
            keypoints, confidence = instant[0], instant[1]
            crowd = rng.uniform(0, 1000, (1, 50, 17, 2)).astype(np.float32)
            keypoints = np.concatenate([keypoints, np.zeros((1, C, 50, 17, 2), np.float32)], 2)
            confidence = np.concatenate([confidence, np.zeros((1, C, 50, 17), np.float32)], 2)
            keypoints[0, 0, -50:], confidence[0, 0, -50:] = crowd[0], 0.5
            instant[:2] = keypoints, confidence
        if i == 41:  # every joint of a person missing in view 1: that person seen by the other views
            instant[1][0, 1, instant[2][0, 1]] = 0.0
            instant[2][0, 1] = -1
        instants.append(instant)
        who.append(here)
    keypoints, confidence, truths = stack(instants)
    found = association.associate(P, keypoints, confidence, threshold_px=20.0)
    detected = (confidence > 0).any(-1)
    assert found.unmatched + (found.detection >= 0).sum() == detected.sum()  # nothing lost
    for i, (truth, here) in enumerate(zip(truths, who)):
        real = {tuple(row) for row in truth[: len(here)].tolist()}
        assert {tuple(row) for row in found.detection[i][found.present[i]].tolist()} == real, i
    followed = tracks.follow(found.points, found.present, LIMBS, tracks.TrackSettings(fps=25.0))
    assert followed.count == 4 and followed.dropped == 0
    identity_of = {}
    for i, (truth, here) in enumerate(zip(truths, who)):
        for m, row in zip(here, truth.tolist()):
            slot = next(s for s in range(found.detection.shape[1]) if found.detection[i, s].tolist() == row)
            identity_of.setdefault(m, set()).add(int(followed.identity[i, slot]))
    assert sorted(identity_of) == [0, 1, 2, 3] and all(len(ids) == 1 for ids in identity_of.values())
    assert sorted(next(iter(ids)) for ids in identity_of.values()) == [0, 1, 2, 3]


def test_tracks_sporadic_false_people_never_take_a_returning_person():
    """Two false detections agreeing across views now and then (a brief person every 15 instants) while a
    person is away: they never become a track, and the person coming back keeps their identity."""
    n = 200
    points = np.full((n, 3, 17, 3), np.nan, np.float32)
    present = np.zeros((n, 3), bool)
    points[:, 0] = BODY + np.array([-2000.0, 0, 0], np.float32)
    points[:, 1] = BODY + np.array([1500.0, 0, 0], np.float32)
    present[:, :2] = True
    present[60:140, 1] = False  # away for 3.2 s at 25 fps
    for i in range(10, n, 15):  # a false person near where the second left, at one instant in 15
        present[i, 2] = True
        points[i, 2] = BODY + np.array([1200.0, 600.0, 0], np.float32)
    points[~present] = np.nan
    followed = tracks.follow(points, present, LIMBS, tracks.TrackSettings(fps=25.0))
    assert followed.count == 2 and followed.dropped == present[:, 2].sum()
    assert (followed.identity[present[:, 1], 1] == 1).all() and (followed.identity[:, 2] == -1).all()


def test_tracks_someone_coming_back_far_away_is_reidentified_by_limbs():
    """A person leaves for 4 s and comes back 5 m from where they left (beyond every gate): the same identity,
    from their limb lengths; a different body coming back there is a new person."""
    n = 250
    other = BODY * np.array([1.15, 1.15, 1.15], np.float32)  # another body: every limb 15% longer
    for body, expected in ((BODY, 1), (other, 2)):
        points = np.full((n, 2, 17, 3), np.nan, np.float32)
        points[:, 0] = other * 0.9 + np.array([0.0, 2500.0, 0], np.float32)
        points[:100, 1] = BODY + np.array([-2500.0, 0, 0], np.float32)
        points[200:, 1] = body + np.array([2500.0, 0, 0], np.float32)
        present = np.isfinite(points).all((-1, -2))
        followed = tracks.follow(points, present, LIMBS, tracks.TrackSettings(fps=25.0))
        assert followed.count == 1 + expected and (followed.identity[200:, 1] == expected).all()
