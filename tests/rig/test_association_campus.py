"""Campus with its calibration and the simulated detector of `benchmarks.people`: several people found,
followed and scored by PCP (skipped where ../shared/data holds no Campus)."""

import numpy as np
import pytest

from benchmarks import people as bench

pytestmark = pytest.mark.skipif(not bench.CAMPUS.exists(), reason="Campus is not in ../shared/data")


@pytest.mark.slow
def test_campus_pcp_several_people_and_one_person():
    campus = bench.load_campus(bench.CAMPUS)
    keypoints, confidence = bench.simulate(campus, seed=0)
    found, followed, points, _ = bench.several(campus, keypoints, confidence, None)
    identity = np.where(np.isfinite(points).all(-1).any(-1), np.arange(points.shape[1]), -1)
    scores = bench.score(campus, points, identity)
    assert scores["average"] >= 96.0 and min(scores["pcp"].values()) >= 95.0
    assert max(scores["mpjpe"].values()) < 80.0 and scores["missed"] <= 10
    # the one-person path follows one of the three: below half of the limbs on average
    one = bench.one_person(campus, keypoints, confidence)
    single = bench.score(campus, one, np.where(np.isfinite(one).any((-1, -2)), 0, -1))
    assert single["average"] < 60.0


def test_pcp_is_the_campus_measure():
    """A limb is correct when the mean of its two end-point errors is at most half its length."""
    truth = np.zeros((14, 3), np.float32)
    truth[:, 2] = np.arange(14) * 100.0  # every limb 100 mm or more long
    moved = truth.copy()
    moved[0, 0] = 99.0  # r ankle 99 mm off: limb (0, 1) has mean error 49.5 <= 50
    assert bench.pcp(moved, truth)[0]
    moved[0, 0] = 101.0
    assert not bench.pcp(moved, truth)[0] and bench.pcp(moved, truth)[1:].all()
    moved[0] = np.nan
    assert not bench.pcp(moved, truth)[0]
