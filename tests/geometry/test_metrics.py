"""Metrics against independent numpy/scipy implementations and hand-computed cases."""

import jax.numpy as jnp
import pytest
import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from jaxpose import metrics



from jaxpose.training import evaluation
def numpy_p_mpjpe(pred, target):
    """Independent oracle: orthogonal Procrustes via the SVD of the cross-covariance, float64."""
    errors = []
    for p, t in zip(pred.astype(np.float64), target.astype(np.float64)):
        p0, t0 = p - p.mean(0), t - t.mean(0)
        u, s, vt = np.linalg.svd(t0.T @ p0)
        d = np.diag([1, 1, np.sign(np.linalg.det(u @ vt))])
        rotation = u @ d @ vt  # maps p0 onto t0: t0 ~ scale * p0 @ rotation.T
        scale = np.trace(np.diag(s) @ d) / (p0**2).sum()
        aligned = scale * p0 @ rotation.T + t.mean(0)
        errors.append(np.linalg.norm(aligned - t, axis=-1).mean())
    return np.array(errors)


def test_p_mpjpe_matches_numpy_oracle():
    rng = np.random.default_rng(0)
    target = rng.normal(0, 300, (64, 17, 3)).astype(np.float32)
    pred = (target + rng.normal(0, 40, target.shape)).astype(np.float32)
    np.testing.assert_allclose(metrics.p_mpjpe(jnp.asarray(pred), jnp.asarray(target)), numpy_p_mpjpe(pred, target), atol=1e-4 * 100, rtol=1e-5)
    # The tolerance above is 1e-4 relative to errors of ~40 mm; check the absolute criterion directly too.
    assert np.abs(np.asarray(metrics.p_mpjpe(jnp.asarray(pred), jnp.asarray(target))) - numpy_p_mpjpe(pred, target)).max() < 1e-2


@given(seed=st.integers(0, 2**31 - 1), scale=st.floats(0.3, 3.0))
def test_p_mpjpe_is_invariant_to_similarity_transforms(seed, scale):
    rng = np.random.default_rng(seed)
    target = rng.normal(0, 300, (8, 17, 3))
    pred = target + rng.normal(0, 30, target.shape)
    rotation = Rotation.random(random_state=seed).as_matrix()
    moved = scale * pred @ rotation.T + rng.normal(0, 500, (1, 1, 3))
    base = np.asarray(metrics.p_mpjpe(jnp.asarray(pred, jnp.float32), jnp.asarray(target, jnp.float32)))
    after = np.asarray(metrics.p_mpjpe(jnp.asarray(moved, jnp.float32), jnp.asarray(target, jnp.float32)))
    np.testing.assert_allclose(after, base, atol=2e-2)
    # A pure similarity transform of the target itself aligns to zero error.
    exact = scale * target @ rotation.T + 100.0
    assert float(metrics.p_mpjpe(jnp.asarray(exact, jnp.float32), jnp.asarray(target, jnp.float32)).max()) < 0.05


def test_p_mpjpe_excludes_reflections():
    rng = np.random.default_rng(1)
    target = rng.normal(0, 300, (4, 17, 3))
    mirrored = target * np.array([-1.0, 1.0, 1.0])
    assert float(metrics.p_mpjpe(jnp.asarray(mirrored, jnp.float32), jnp.asarray(target, jnp.float32)).min()) > 10.0


def test_mpjpe_and_n_mpjpe_hand_computed():
    target = jnp.zeros((1, 2, 3)).at[0, 1].set(jnp.array([100.0, 0.0, 0.0]))
    pred = target.at[0, 1, 0].set(130.0)
    np.testing.assert_allclose(metrics.mpjpe(pred, target), [15.0])  # errors 0 and 30 -> mean 15
    # Scale alone fixes a pure scaling.
    np.testing.assert_allclose(metrics.n_mpjpe(target * 1.7, target), [0.0], atol=1e-4)
    # n_mpjpe <= mpjpe always (scale 1 is one candidate).
    rng = np.random.default_rng(2)
    a, b = jnp.asarray(rng.normal(0, 100, (16, 17, 3))), jnp.asarray(rng.normal(0, 100, (16, 17, 3)))
    assert bool(jnp.all(metrics.n_mpjpe(a, b) <= metrics.mpjpe(a, b) + 1e-4))


def test_pck_and_auc_hand_computed():
    target = jnp.zeros((1, 4, 3))
    # Joint errors 0, 100, 150, 200 mm along x.
    pred = target.at[0, :, 0].set(jnp.array([0.0, 100.0, 150.0, 200.0]))
    np.testing.assert_allclose(metrics.pck(pred, target), [0.75])  # 150 counts (<=)
    # AUC: thresholds 0..150 by 5 (31 values); joint 0 counts at all 31, joint 1 at 100..150 (11),
    # joint 2 at 150 only (1), joint 3 never: (31 + 11 + 1) / (31 * 4).
    np.testing.assert_allclose(metrics.auc(pred, target), [(31 + 11 + 1) / 124], rtol=1e-6)


def test_per_joint_metrics_average_to_the_pose_metrics():
    rng = np.random.default_rng(3)
    target = jnp.asarray(rng.normal(0, 300, (20, 17, 3)), jnp.float32)
    pred = target + jnp.asarray(rng.normal(0, 40, target.shape), jnp.float32)
    per_pose = metrics.pose_metrics(pred, target)
    per_joint = metrics.per_joint_metrics(pred, target)
    assert per_joint["p_mpjpe"].shape == (20, 17)
    for name in ("mpjpe", "p_mpjpe"):
        np.testing.assert_allclose(per_joint[name].mean(-1), per_pose[name], rtol=1e-5)
    # A single displaced joint shows up in its own column of the unaligned per-joint error only.
    moved = pred.at[:, 5].set(target[:, 5] + jnp.array([100.0, 0.0, 0.0]))
    errors = metrics.per_joint_metrics(moved, target)["mpjpe"]
    np.testing.assert_allclose(errors[:, 5], 100.0, rtol=1e-5)


def test_evaluate_poses_over_the_agreeing_joints_ignores_the_others():
    """The "agreeing_joints" summary aligns and scores the listed joints alone: a joint defined
    differently by the 2D source (here displaced by 200 mm in every pose) changes the all-joint
    P-MPJPE but not the agreeing one, which equals the numpy oracle on the sliced poses."""
    rng = np.random.default_rng(5)
    target = rng.normal(0, 300, (12, 2, 16, 3)).astype(np.float32)
    pred = (target + rng.normal(0, 30, target.shape)).astype(np.float32)
    shifted = pred.copy()
    shifted[..., 7, :] += np.float32(200.0)
    agreeing = np.array([j for j in range(16) if j not in (7, 9)])
    groups = np.array(["a", "b"] * 6)
    plain = evaluation.evaluate_poses(pred, target, groups, agreeing_joints=agreeing)
    moved = evaluation.evaluate_poses(shifted, target, groups, agreeing_joints=agreeing)
    assert moved["overall"]["p_mpjpe"] > plain["overall"]["p_mpjpe"] + 5
    oracle = numpy_p_mpjpe(pred[..., agreeing, :].reshape(24, -1, 3), target[..., agreeing, :].reshape(24, -1, 3)).mean()
    for summary in (plain, moved):
        np.testing.assert_allclose(summary["agreeing_joints"]["overall"]["p_mpjpe"], oracle, rtol=1e-4)
        assert set(summary["agreeing_joints"]) == {"overall", "group_average"}
    assert "agreeing_joints" not in evaluation.evaluate_poses(pred, target, groups)


# ---------------------------------------------------------------------------------------------
# Motion metrics: velocity (MPJVE) and acceleration errors along each sequence


def _numpy_motion(pred, target, step):
    """Oracle for one sequence of one view, sorted, every sample `step` frames apart: [T, J, 3] -> ([T-1], [T-2])."""
    velocity = np.linalg.norm(np.diff(pred, axis=0) - np.diff(target, axis=0), axis=-1).mean(-1) / step
    acceleration = np.linalg.norm(np.diff(pred, 2, axis=0) - np.diff(target, 2, axis=0), axis=-1).mean(-1) / step**2
    return velocity, acceleration


@given(
    lengths=st.lists(st.integers(1, 9), min_size=1, max_size=3),
    step=st.integers(1, 5),
    seed=st.integers(0, 2**16),
)
def test_motion_errors_follow_each_sequence_in_frame_order_whatever_the_sample_order(lengths, step, seed):
    rng = np.random.default_rng(seed)
    N, C, J = sum(lengths), 2, 4
    target = rng.normal(0, 100, (N, C, J, 3))
    pred = target + rng.normal(0, 10, target.shape)
    sequences = np.repeat([f"s{i}" for i in range(len(lengths))], lengths)
    frames = np.concatenate([100 * i + step * np.arange(n) for i, n in enumerate(lengths)])
    shuffle = rng.permutation(N)
    motion = evaluation.motion_errors(pred[shuffle], target[shuffle], sequences[shuffle], frames[shuffle])
    velocity, acceleration = np.empty((N, C)), np.empty((N, C))
    velocity[shuffle], acceleration[shuffle] = motion["mpjve"], motion["accel_error"]  # back to sorted order
    start = 0
    for n in lengths:
        rows = slice(start, start + n)
        for c in range(C):
            v, a = _numpy_motion(pred[rows, c], target[rows, c], step if n > 1 else 1)
            np.testing.assert_allclose(velocity[rows, c][:-1], v, rtol=1e-5)
            np.testing.assert_allclose(acceleration[rows, c][1:-1], a, rtol=1e-5)
            assert np.isnan(velocity[start + n - 1, c]) and np.isnan(acceleration[start, c])  # no neighbour
            assert n < 2 or np.isnan(acceleration[start + n - 1, c])
        start += n


def test_motion_errors_of_one_jittered_frame_and_of_an_offset_and_gaps():
    T, J, step = 7, 3, 5
    target = np.cumsum(np.ones((T, 1, J, 3)), axis=0) * 10.0  # moving steadily
    frames, sequences = step * np.arange(T), np.zeros(T, int)
    offset = evaluation.motion_errors(target + 25.0, target, sequences, frames)
    assert np.nanmax(offset["mpjve"]) == 0 and np.nanmax(offset["accel_error"]) == 0  # a constant error does not move
    jitter = target.copy()
    jitter[3] += np.array([3.0, 4.0, 0.0])  # 5 mm at frame 15, every joint
    motion = evaluation.motion_errors(jitter, target, sequences, frames)
    np.testing.assert_allclose(motion["mpjve"][:, 0], [0, 0, 1, 1, 0, 0, np.nan])  # 5 mm over 5 frames
    np.testing.assert_allclose(motion["accel_error"][:, 0], [np.nan, 0, 0.2, 0.4, 0.2, 0, np.nan])  # 5, 10, 5 mm / 25
    # A missing sample breaks the chain: no difference across the gap, and invalid views are not used.
    valid = np.ones((T, 1), bool)
    valid[4] = False
    motion = evaluation.motion_errors(jitter, target, sequences, frames, valid)
    assert np.isnan(motion["mpjve"][[3, 4], 0]).all() and np.isnan(motion["accel_error"][[3, 4, 5], 0]).all()
    gapped = evaluation.motion_errors(jitter[[0, 1, 2, 4, 5]], target[[0, 1, 2, 4, 5]], sequences[:5], frames[[0, 1, 2, 4, 5]])
    assert np.isnan(gapped["mpjve"][2, 0]) and evaluation.frame_step(sequences[:5], frames[[0, 1, 2, 4, 5]]) == step


def test_evaluate_poses_reports_motion_metrics_per_group_over_the_poses_that_have_them():
    rng = np.random.default_rng(1)
    target = rng.normal(0, 100, (6, 2, 5, 3))
    pred = target + rng.normal(0, 5, target.shape)
    groups = np.array(["a"] * 3 + ["b"] * 3)
    summary = evaluation.evaluate_poses(pred, target, groups, sequences=groups, frames=np.array([0, 1, 2, 0, 1, 2]))
    motion = evaluation.motion_errors(pred, target, groups, np.array([0, 1, 2, 0, 1, 2]))
    assert summary["groups"]["a"]["mpjve"] == pytest.approx(np.nanmean(motion["mpjve"][:3]), rel=1e-5)
    assert summary["overall"]["accel_error"] == pytest.approx(np.nanmean(motion["accel_error"]), rel=1e-5)
    assert "mpjve" not in evaluation.evaluate_poses(pred, target, groups)["overall"]
    table = evaluation.markdown_table({"x": summary}, "accel_error")
    assert "nan" not in table


def test_motion_errors_refuse_a_sequence_name_shared_by_two_recordings():
    target = np.zeros((4, 1, 3, 3))
    with pytest.raises(ValueError, match=r"sequence 'Walking 1' has frame 0 more than once"):
        evaluation.motion_errors(target, target, np.array(["Walking 1"] * 4), np.array([0, 5, 0, 5]))


def test_group_average_skips_groups_without_motion_but_not_a_broken_metric():
    per_pose = {"p_mpjpe": np.array([10.0, 20.0, np.nan, np.nan]), "mpjve": np.array([1.0, np.nan, np.nan, np.nan])}
    summary = evaluation.summarize(per_pose, np.array(["a", "a", "b", "b"]))
    assert np.isnan(summary["group_average"]["p_mpjpe"])  # a NaN error is a bug to see, not to average away
    assert summary["group_average"]["mpjve"] == 1.0  # group b has no consecutive samples: no velocity to count
