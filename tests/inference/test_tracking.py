"""Following people through frames (`jaxpose.serving.tracking.follow_people`)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxpose.serving.tracking import NOT_FOLLOWED, follow_people

JOINTS = 12


def _body(rng: np.random.Generator, height: float) -> np.ndarray:
    """A pose's shape [J, 2] about its centre: random keypoints in a box of the given height, half as wide."""
    return rng.uniform(-0.5, 0.5, (JOINTS, 2)) * (height / 2, height)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    frames=st.integers(20, 60),
    separation=st.floats(1.0, 3.0),  # heights apart in the first frame: 0.05-0.15 heights per frame
    height=st.floats(200, 400),
    ratio=st.floats(0.9, 1.1),
    vertical=st.floats(15, 40),
    above=st.booleans(),
    noise=st.floats(0.0, 2.0),
    missing=st.floats(0.0, 0.3),
)
def test_two_people_crossing_paths_keep_their_tracks(seed, frames, separation, height, ratio, vertical, above, noise, missing):
    """Two people of much the same build walk towards each other and past, their keypoints overlapping where
    they meet (one 15-40 px higher in the image, several times the detector's noise of up to 2 px), listed in
    a random order in each frame, each missing from some frames and with some joints undetected: each keeps
    one track, and the two tracks differ."""
    speed = separation * height / frames
    rng = np.random.default_rng(seed)
    body = _body(rng, height)
    bodies = [body, body * ratio + rng.normal(0, 0.02 * height, body.shape)]
    meet = frames / 2
    rows, people = [], []
    for frame in range(frames):
        for person in rng.permutation(2):
            if 1 < frame < frames - 1 and rng.random() < missing:  # seen in its first two frames: a velocity
                continue
            direction = 1 if person == 0 else -1
            offset = (vertical if above else -vertical) if person else 0.0
            centre = np.array([500 + direction * speed * (frame - meet), 500 + offset])
            keypoints = centre + bodies[person] + rng.normal(0, noise, (JOINTS, 2))
            detected = rng.random(JOINTS) > 0.2
            detected[:2] = True  # a couple of joints every detector finds
            rows.append((frame, keypoints, detected))
            people.append(person)
    frame_numbers = np.array([r[0] for r in rows])
    tracks = follow_people(frame_numbers, np.stack([r[1] for r in rows]), np.stack([r[2] for r in rows]), max_gap=frames)
    people = np.array(people)
    first, second = (set(tracks[people == p].tolist()) for p in (0, 1))
    assert len(first) == 1 and len(second) == 1 and first != second


def test_numbered_by_first_appearance_a_new_track_after_the_gap_limit_and_none_without_keypoints():
    body = _body(np.random.default_rng(0), 300)
    here, there = body + 300, body + 900
    frames = np.array([5, 5, 6, 7, 7, 20, 20])
    keypoints = np.stack([there, here, here, here, there, here, here])
    valid = np.ones((7, JOINTS), bool)
    valid[6] = False  # nothing detected
    tracks = follow_people(frames, keypoints, valid, max_gap=10)
    # Frame 5 lists the far person first; the near one is gone from 8 to 19 (12 frames > 10): a new track.
    assert tracks.tolist() == [0, 1, 1, 1, 0, 2, NOT_FOLLOWED]
    assert follow_people(frames, keypoints, valid, max_gap=12).tolist()[5] == 1


def test_a_pose_far_from_every_track_starts_its_own():
    body = _body(np.random.default_rng(1), 300)
    tracks = follow_people(np.array([0, 1]), np.stack([body, body + 400]), np.ones((2, JOINTS), bool))
    assert tracks.tolist() == [0, 1]  # 400 px is more than half the person's size


def test_refusals():
    with pytest.raises(ValueError, match="gate must be > 0"):
        follow_people(np.zeros(1), np.zeros((1, 2, 2)), np.ones((1, 2), bool), gate=0)
