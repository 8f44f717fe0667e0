"""A view whose root (pelvis) and hips are occluded is lifted about the fused root's projection
(`jaxpose.reconstruction.recording.lift_and_reconstruct`): on an exact moving scene with a lifter that
knows the truth, a joint only such a view detects is fixed (no gap) at the truth, the root given to the
lifter is the projection of the interpolated root track (a numpy oracle), and without the second pass
the same frames have a gap."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from geometry_helpers import random_poses, random_rig

from jaxpose.camera import Cameras
from jaxpose.reconstruction.fusion import Provenance
from jaxpose.reconstruction.recording import (
    RecordingInput,
    fill_recording,
    fuse_recording,
    lift_and_reconstruct,
    lift_views,
    root_from_world,
    root_track,
)
from jaxpose.skeleton import H36M_17, ROOT

F, C, J = 40, 4, 17
OCCLUDED = range(12, 24)  # frames at which every view misses the root and the left hip
WRIST = H36M_17.joint_names.index("RWrist")
LEFT_HIP = H36M_17.joint_names.index("LHip")


class OracleLifter(SimpleNamespace):
    """A frame lifter that lifts each pose it is given to the true root-relative pose in that camera's
    axes (the view and frame found by the detections it is given, row by row: `lift_views` may give it
    every view-frame in one call), and records, per view, the root pixels it was given."""

    model_config = SimpleNamespace(temporal_window=1)

    def predict(self, keypoints, intrinsics, confidence):
        views, frames = self.pixels.shape[:2]
        candidates = self.pixels.reshape(views * frames, 1, J, 2)  # [view-frame, 1, J, 2]
        seen = confidence[None, ..., None] > 0
        errors = np.nanmean(np.where(seen, np.abs(keypoints[None] - candidates), np.nan), axis=(-1, -2))  # [view-frame, rows]
        view, frame = np.divmod(np.nanargmin(errors, axis=0), frames)
        for v in np.unique(view):
            rows = np.flatnonzero(view == v)[np.argsort(frame[view == v])]
            self.given_roots.append((int(v), keypoints[rows, ROOT].copy(), confidence[rows, ROOT].copy()))
        lifted = self.lifted[view, frame]
        return np.where(confidence[:, ROOT, None, None] > 0, lifted, np.nan).astype(np.float32)


def moving_scene(seed: int):
    rng = np.random.default_rng(seed)
    rig = random_rig(rng, C)
    K, R, t = (np.asarray(field, np.float64) for field in (rig.K, rig.R, rig.t))
    u, _, vt = np.linalg.svd(R)
    R = u @ vt  # orthonormal in float64 (see test_fusion.exact_scene)
    pose = random_poses(rng, 1, J).astype(np.float64)[0]
    walk = np.linspace(-400.0, 400.0, F)[:, None] * np.array([1.0, 0.5, 0.0])  # 800 mm along x in 40 frames
    truth = pose[None] + walk[:, None]  # [F, J, 3]
    in_camera = np.einsum("cab,fjb->fcja", R, truth) + t[None, :, None]
    homogeneous = np.einsum("cab,fcjb->fcja", K, in_camera)
    pixels = homogeneous[..., :2] / homogeneous[..., 2:]
    confidence = np.ones((F, C, J), np.float32)
    confidence[OCCLUDED.start : OCCLUDED.stop, :, ROOT] = 0.0
    confidence[OCCLUDED.start : OCCLUDED.stop, :, LEFT_HIP] = 0.0
    confidence[OCCLUDED.start : OCCLUDED.stop, 1:, WRIST] = 0.0  # the wrist: view 0 alone
    inputs = RecordingInput(
        "walk", np.arange(F), Cameras(K=K, R=R, t=t), pixels.astype(np.float32), confidence, truth.astype(np.float32)
    )
    lifter = OracleLifter(
        skeleton=H36M_17, joint_names=H36M_17.joint_names, num_joints=J, source="oracle",
        pixels=np.moveaxis(pixels, 1, 0), lifted=np.moveaxis(in_camera - in_camera[..., :1, :], 1, 0), given_roots=[],
    )  # fmt: skip
    return inputs, lifter, truth


def test_a_joint_only_a_rootless_view_sees_is_fused_at_the_truth_without_a_gap():
    inputs, lifter, truth = moving_scene(0)
    motion, lifted = lift_and_reconstruct(lifter, inputs)
    assert np.isfinite(lifted[OCCLUDED.start : OCCLUDED.stop, :, ROOT]).all()  # every view lifted
    assert motion.segments.tolist() == [[0, F]] and motion.dropped_frames == 0
    np.testing.assert_allclose(motion.points, truth, atol=0.05)  # mm
    assert (motion.provenance[OCCLUDED.start : OCCLUDED.stop, WRIST] == Provenance.FUSED).all()

    # Without the second pass (the first pass's lifts only), those frames had a gap at the wrist.
    first = fill_recording(inputs, fuse_recording(inputs, lift_views(lifter, inputs)), max_gap=5)
    assert np.isnan(first.fusion.points[OCCLUDED.start : OCCLUDED.stop, WRIST]).all()
    assert first.dropped_frames == len(OCCLUDED)


def test_the_lifter_is_given_the_projection_of_the_interpolated_root():
    inputs, lifter, truth = moving_scene(1)
    fusion = fuse_recording(inputs, lift_views(lifter, inputs))
    assert np.isnan(fusion.points[OCCLUDED.start : OCCLUDED.stop, ROOT]).all()  # no view gave a root there
    track = root_track(fusion.points[:, ROOT])
    # Oracle: the root is known before and after, so its track there is the straight line between the
    # frames around the occlusion (the scene walks in a straight line: the truth).
    np.testing.assert_allclose(track, truth[:, ROOT], atol=0.05)
    lifter.given_roots.clear()
    relifted = lift_views(lifter, inputs, track)
    assert {view for view, _, _ in lifter.given_roots} == set(range(C))
    K, R, t = (np.asarray(getattr(inputs.cameras, name)) for name in ("K", "R", "t"))
    for view, roots, confidence in lifter.given_roots:
        x = track[OCCLUDED.start : OCCLUDED.stop] @ R[view].T + t[view]
        expected = (x @ K[view].T)[:, :2] / x[:, 2:]
        np.testing.assert_allclose(roots[OCCLUDED.start : OCCLUDED.stop], expected, rtol=1e-5)
        assert (confidence[OCCLUDED.start : OCCLUDED.stop] > 0).all()
    # Only the view-frames without a root are lifted again.
    assert np.isfinite(relifted[OCCLUDED.start : OCCLUDED.stop]).all()
    outside = np.ones(F, bool)
    outside[OCCLUDED.start : OCCLUDED.stop] = False
    assert np.isnan(relifted[outside]).all()


def test_root_track_and_root_from_world_edges():
    roots = np.full((6, 3), np.nan, np.float32)
    assert np.isnan(root_track(roots)).all()  # nothing known: nothing invented
    roots[2], roots[4] = (0.0, 0.0, 0.0), (20.0, 40.0, 60.0)
    np.testing.assert_allclose(root_track(roots), [[0, 0, 0]] * 3 + [[10, 20, 30]] + [[20, 40, 60]] * 2)
    # A root behind the camera, or a view-frame that detects nothing, gets no root.
    cameras = Cameras(K=np.eye(3)[None], R=np.eye(3)[None], t=np.zeros((1, 3)))
    keypoints, confidence = np.zeros((3, 1, J, 2), np.float32), np.zeros((3, 1, J), np.float32)
    confidence[:2, :, 5] = 1.0
    points = np.array([[0.0, 0.0, 1000.0], [0.0, 0.0, -1000.0], [0.0, 0.0, 1000.0]])
    _, given = root_from_world(cameras, keypoints, confidence, points)
    assert given[:, 0, ROOT].tolist() == [1.0, 0.0, 0.0]


def test_anchored_lifts_remove_a_slowly_changing_lift_error():
    """A lift off by an error that changes linearly in time is put back on the truth between the frames
    the cameras fix; beyond the last one the last offset is held; a joint never detected keeps its lift."""
    from jaxpose.reconstruction.recording import anchored_lifts

    rng = np.random.default_rng(3)
    frames, joints = 30, 3
    truth = rng.normal(0, 500, (frames, joints, 3)) + np.linspace(0, 900, frames)[:, None, None]
    bias = np.linspace(0, 1, frames)[:, None] * np.array([60.0, -30.0, 90.0]) + np.array([10.0, 20.0, -40.0])
    placed = np.stack([truth + bias[:, None], truth + bias[:, None] + 8.0, np.full_like(truth, np.nan)], 1)  # [F, C=3, J, 3]
    guess = placed[:, :2].mean(1)
    provenance = np.full((frames, joints), Provenance.TRIANGULATED, np.int8)
    provenance[5:20, 0] = Provenance.LIFTED  # between two detected runs
    provenance[22:, 1] = Provenance.LIFTED  # to the end
    provenance[:, 2] = Provenance.LIFTED  # never detected
    points = np.where((provenance == Provenance.LIFTED)[..., None], guess, truth).astype(np.float32)
    anchored = anchored_lifts(points, provenance, placed.astype(np.float32))
    np.testing.assert_allclose(anchored[:, 0], truth[:, 0], atol=1e-2)
    held = truth[22:, 1] + (bias[22:] - bias[21])  # the offset of frame 21 held
    np.testing.assert_allclose(anchored[22:, 1], held, atol=1e-2)
    np.testing.assert_array_equal(anchored[:, 2], points[:, 2])
    np.testing.assert_array_equal(anchored[provenance != Provenance.LIFTED], points[provenance != Provenance.LIFTED])
