"""Recordings grouped by rig (`jaxpose.calibration.sessions`).

Two simulated sessions: a rig, and the same rig with every camera moved by 100-500 mm and turned by
1-3 degrees (`jaxpose.synthetic.sessions.moved_rig`), each filming the same subject in different
motions through the default detector (3-8 px noise, outliers, swaps, missing joints).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxpose.calibration import CalibrationConfig, RigDetections
from jaxpose.calibration.sessions import FIT_MARGIN_PX, find_sessions, group_by_fit, group_by_label, pooled_detections, rig_fit_px
from jaxpose.skeleton import H36M_17
from jaxpose.synthetic import SyntheticConfig, make_rig, sample_bone_lengths, sample_motion
from jaxpose.synthetic.sessions import moved_rig, record

CONFIG = SyntheticConfig()
NAMES = ("c0", "c1", "c2", "c3")


def recordings(seed: int, plan, frames: int = 100):
    """{name: RigDetections} of `plan` [(name, rig letter, motion)], and the rigs {letter: Cameras}."""
    rng = np.random.default_rng(seed)
    rigs = {"A": make_rig(rng, CONFIG)}
    rigs["B"] = moved_rig(rng, rigs["A"])
    rigs["C"] = moved_rig(rng, rigs["A"])
    bones = sample_bone_lengths(rng)
    result = {}
    for name, letter, motion in plan:
        keypoints, confidence = record(rng, rigs[letter], sample_motion(rng, motion, bones, frames, CONFIG).poses, CONFIG)
        result[name] = RigDetections(
            keypoints, confidence, NAMES, np.full((4, 2), 1000), H36M_17, K=np.asarray(rigs["A"].K, np.float64), source=name
        )
    return result, rigs


TWO_SESSIONS = [("a1", "A", "walking"), ("a2", "A", "reaching"), ("b1", "B", "turning"), ("b2", "B", "gesturing")]


@settings(max_examples=4, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_the_true_rigs_tell_the_moved_session_apart(seed):
    """Through the rig that filmed it, a recording re-projects at the detector's noise; through the moved
    rig, its worst camera is far beyond the margin; grouped, the two sessions come out."""
    data, rigs = recordings(seed, TWO_SESSIONS)
    names = tuple(data)
    fit = np.array([[np.nanmax(rig_fit_px(rigs[rig[0].upper()], data[name])) for name in names] for rig in names])
    same = np.array([[a[0] == b[0] for b in names] for a in names])
    assert fit[same].max() < 6.0  # the detector's 3-8 px noise, robustly triangulated
    assert fit[~same].min() > fit[same].max() + 3 * FIT_MARGIN_PX
    grouping = group_by_fit(names, fit)
    assert [session.recordings for session in grouping.sessions] == [("a1", "a2"), ("b1", "b2")]
    assert grouping.unfitted == () and grouping.session_of("b2") == "session2"


def test_a_sessions_recordings_pooled():
    data, _ = recordings(3, TWO_SESSIONS[:2], frames=40)
    pooled = pooled_detections(data, ["a2", "a1"])
    np.testing.assert_array_equal(pooled.keypoints, np.concatenate([data["a2"].keypoints, data["a1"].keypoints]))
    assert pooled.confidence.shape == (80, 4, 17) and pooled.source == "session of a2, a1"
    other = RigDetections(data["a1"].keypoints[:, :3], data["a1"].confidence[:, :3], NAMES[:3], np.full((3, 2), 1000), H36M_17)
    with pytest.raises(ValueError, match=r"recording 'b' has cameras \('c0', 'c1', 'c2'\)"):
        pooled_detections({"a": data["a1"], "b": other}, ["a", "b"])


def test_complete_linkage_does_not_chain_and_a_rigless_recording_joins_the_session_it_fits():
    nan = np.nan
    fit = np.array([
        # a     b     c     d     e (no rig of its own)
        [3.0, 5.0, 9.0, 40.0, 4.0],
        [5.0, 3.0, 5.0, 40.0, 4.5],
        [9.0, 5.0, 3.0, 40.0, 30.0],
        [40.0, 40.0, 40.0, 3.0, 40.0],
        [nan, nan, nan, nan, nan],
    ])  # fmt: skip
    grouping = group_by_fit("abcde", fit)
    # a-b and b-c fit within 3 px, a-c do not: b goes with one of them, never all three together.
    assert [session.recordings for session in grouping.sessions] == [("a", "b", "e"), ("c",), ("d",)]
    assert grouping.sessions[0].reprojection_px == 3.0
    fit[:4, 4] = 40.0  # no rig explains e
    assert group_by_fit("abcde", fit).unfitted == ("e",)


def test_a_weak_rig_that_misses_a_recording_its_better_rig_explains_still_shares_it():
    """w's rig (a subject on one spot: degrees off) leaves a's detections 6 px above a's own; a's rig explains w."""
    fit = np.array([[3.0, 4.0, 50.0], [9.0, 4.0, 50.0], [50.0, 50.0, 3.0]])
    assert [session.recordings for session in group_by_fit(["a", "w", "m"], fit).sessions] == [("a", "w"), ("m",)]
    fit[0, 1] = 9.0  # neither explains the other
    assert len(group_by_fit(["a", "w", "m"], fit).sessions) == 3


def test_labels_are_taken_as_given():
    grouping = group_by_label(["walk1", "walk2", "run1"], ["day1", "day2", "day1"])
    assert grouping.method == "labels"
    assert [(session.name, session.recordings) for session in grouping.sessions] == [("day1", ("walk1", "run1")), ("day2", ("walk2",))]
    with pytest.raises(ValueError, match="3 recordings but 2 session labels"):
        group_by_label(["a", "b", "c"], ["x", "y"])
    with pytest.raises(ValueError, match=r"repeat: \['a'\]"):
        group_by_label(["a", "a"], ["x", "y"])
    with pytest.raises(ValueError, match=r"fit must be \[2, 2\]"):
        group_by_fit("ab", np.zeros((3, 3)))


@pytest.mark.slow  # four calibrations and two refused ones: 2 min 43 s on 2 cores (12 min shared with other jobs)
def test_sessions_found_from_the_detections_alone():
    plan = TWO_SESSIONS + [("a3", "A", "walking"), ("c1", "C", "walking")]
    data, _ = recordings(20261126, plan, frames=300)
    for short in ("a3", "c1"):  # too short to calibrate on their own (20 frames < min_frames 30)
        data[short] = RigDetections(data[short].keypoints[:20], data[short].confidence[:20], NAMES, np.full((4, 2), 1000),
                                    H36M_17, K=data[short].K, source=short)  # fmt: skip
    grouping = find_sessions(data, CalibrationConfig(max_frames=150))
    assert [session.recordings for session in grouping.sessions] == [("a1", "a2", "a3"), ("b1", "b2")]
    assert grouping.unfitted == ("c1",) and set(grouping.failures) == {"a3", "c1"}
    assert all(session.reprojection_px < 6.0 for session in grouping.sessions)
    assert set(grouping.calibrations) == {"a1", "a2", "b1", "b2"}


def test_until_explained_recovers_rigs_only_until_every_recording_is_explained(monkeypatch):
    """The search of the rig loader: rigs from the recordings where the person moves most first, none from a
    recording a rig already explains, one after all from a recording whose session's rigs do not all explain
    it; the fits come from a table (rig of recording i, recording j), the calibrations are counted."""
    from jaxpose.calibration import sessions

    table = {  # rig -> its worst camera's median error on each recording (px)
        "a1": {"a1": 4.0, "a2": 4.5, "a3": 6.5, "b1": 90.0, "b2": 90.0},
        "b1": {"a1": 90.0, "a2": 90.0, "a3": 9.0, "b1": 4.0, "b2": 4.2},
        "a3": {"a1": 4.3, "a2": 4.4, "a3": 4.1, "b1": 90.0, "b2": 90.0},
    }
    spread = {"a1": 50.0, "b1": 40.0, "a3": 30.0, "a2": 20.0, "b2": 10.0}  # the person's motion per recording
    class Recording(str):  # a recording's detections, by name
        camera_names = NAMES

    data = {name: Recording(name) for name in ("a2", "a1", "a3", "b2", "b1")}
    calibrated = []

    def calibrate(detections, config):
        calibrated.append(detections)
        return type("Rig", (), {"cameras": detections})

    monkeypatch.setattr(sessions, "calibrate", calibrate)
    monkeypatch.setattr(sessions, "motion", lambda detections, min_confidence: spread[detections])
    monkeypatch.setattr(sessions, "rig_fit_px", lambda rig, detections, min_confidence: np.array([table[rig][detections]]))
    grouping = sessions.find_sessions(data, until_explained=True)
    assert calibrated == ["a1", "b1"]  # a3, a2 and b2 explained by a1's or b1's rig: not calibrated
    assert [session.recordings for session in grouping.sessions] == [("a2", "a1", "a3"), ("b2", "b1")]
    # a3 within 3 px of a1's own 4.0 no longer: neither a1's rig nor b1's explains it, so a3 gets its own rig,
    # which explains a1 and a2: one session of a1, a2, a3 still.
    table["a1"]["a3"] = 7.5
    calibrated.clear()
    grouping = sessions.find_sessions(data, until_explained=True)
    assert calibrated == ["a1", "b1", "a3"]
    assert [session.recordings for session in grouping.sessions] == [("a2", "a1", "a3"), ("b2", "b1")]
