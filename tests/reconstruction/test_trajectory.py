"""The trajectory over a recording (jaxpose.reconstruction.trajectory): on a simulated walk seen by an exact
rig and fused per instant as `jaxpose.reconstruct` fuses it, and against a dense scipy least squares."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
from geometry_helpers import random_rig
from scipy.optimize import least_squares

from jaxpose.camera import Cameras
from jaxpose.reconstruction.fusion import FusionConfig, Provenance, fuse
from jaxpose.reconstruction.motion_quality import acceleration_error, limb_length_spread
from jaxpose.reconstruction.recording import smooth_recording
from jaxpose.reconstruction.trajectory import NOISE_GRID_MM_S2, TrajectoryConfig, limb_lengths, process_noise, solve_trajectory
from jaxpose.skeleton import H36M_17
from jaxpose.synthetic import SyntheticConfig, sample_bone_lengths, sample_motion

FPS = 50.0
BONES = H36M_17.bones
SIMULATED = FusionConfig(lift_lateral_mm=20.0, lift_depth_mm=50.0)  # test_fusion.py's model of an exact lifter
# The simulated steps accelerate a foot by up to 28 m/s^2 (median 4): a process noise for them, not the
# default chosen on Human3.6M, so that these tests do not move with that choice.
WALKING = TrajectoryConfig(acceleration_mm_s2=10000.0)


@dataclasses.dataclass
class Walk:
    cameras: Cameras  # float64 fields [C, ...]
    truth: np.ndarray  # [F, J, 3] world mm
    pixels: np.ndarray  # [F, C, J, 2] exact projections
    lifted: np.ndarray  # [F, C, J, 3] the true root-relative pose in each camera's axes


def walk(seed: int, frames: int = 150, views: int = 4, rigid: bool = False, fps: float = FPS) -> Walk:
    """A simulated person walking (`sample_motion`, constant limb lengths) sampled at `fps`, its path centred
    on the rig's target; `rigid`: its first pose carried at a constant velocity instead (no acceleration)."""
    rng = np.random.default_rng(seed)
    truth = sample_motion(rng, "walking", sample_bone_lengths(rng), frames, SyntheticConfig(fps=fps)).poses.astype(np.float64)
    truth[..., :2] -= truth[:, :1, :2].mean(0)
    if rigid:
        truth = truth[:1] + np.arange(frames)[:, None, None] * np.array([8.0, -3.0, 0.5])
    rig = random_rig(rng, views)
    K, R, t = (np.asarray(field, np.float64) for field in (rig.K, rig.R, rig.t))
    u, _, vt = np.linalg.svd(R)
    R = u @ vt  # exactly orthonormal (test_fusion.py's exact_scene)
    in_camera = np.einsum("cab,njb->ncja", R, truth) + t[None, :, None]
    homogeneous = np.einsum("cab,ncjb->ncja", K, in_camera)
    return Walk(Cameras(K=K, R=R, t=t), truth, homogeneous[..., :2] / homogeneous[..., 2:], in_camera - in_camera[..., :1, :])


def fused(scene: Walk, pixel_noise: float = 0.0, seed: int = 0, confidence: np.ndarray | None = None):
    """The per-instant fusion of the walk's detections (with Gaussian pixel noise) and exact lifts (none of
    a view that detects nothing, as `lift_views` lifts none)."""
    noise = np.random.default_rng(seed).normal(0.0, pixel_noise, scene.pixels.shape) if pixel_noise else 0.0
    confidence = np.ones(scene.pixels.shape[:-1]) if confidence is None else confidence
    lifted = np.where((confidence > 0).any(-1)[..., None, None], scene.lifted, np.nan)
    return fuse(scene.cameras, scene.pixels + noise, confidence, lifted, SIMULATED)


def solve(fusion, config: TrajectoryConfig = WALKING):
    return solve_trajectory(fusion.points, fusion.covariance, fusion.provenance, BONES, FPS, config)


def test_exact_evidence_of_a_motion_without_acceleration_is_returned_unchanged():
    """A body carried at constant velocity: every term is 0 at the truth, so the track is the evidence."""
    scene = walk(0, rigid=True)
    fusion = fused(scene)
    assert np.abs(fusion.points - scene.truth).max() < 1e-3
    track = solve(fusion, TrajectoryConfig())
    assert np.abs(track.points - scene.truth).max() < 2e-3
    assert track.weight.min() > 0.99  # nothing taken for an outlier
    children, parents = zip(*BONES)
    true_lengths = np.linalg.norm(scene.truth[0, list(children)] - scene.truth[0, list(parents)], axis=-1)
    np.testing.assert_allclose(track.limb_lengths, true_lengths, atol=1e-3)


def test_exact_evidence_of_a_walk_moves_by_less_than_its_uncertainty():
    """A real walk accelerates, which the motion prior resists a little: the track stays within a fraction
    of the evidence's own uncertainty (~14 mm here) at most instants (the sharpest accelerations of the
    simulated steps, up to 28 m/s^2, are rounded off by more)."""
    scene = walk(1)
    fusion = fused(scene)
    track = solve(fusion)
    moved = np.linalg.norm(track.points - fusion.points, axis=-1) / fusion.uncertainty
    assert np.median(moved) < 0.25 and np.percentile(moved, 90) < 0.5


def test_noise_is_smoothed_away_limbs_keep_their_length():
    scene = walk(2)
    fusion = fused(scene, pixel_noise=3.0, seed=2)
    track = solve(fusion)
    per_instant, _ = acceleration_error(fusion.points, scene.truth)
    smoothed, _ = acceleration_error(track.points, scene.truth)
    assert smoothed < 0.3 * per_instant
    spread_before = np.nanmean(limb_length_spread(fusion.points, BONES))
    spread_after = np.nanmean(limb_length_spread(track.points, BONES))
    assert spread_after < 0.5 * spread_before
    error_before = np.linalg.norm(fusion.points - scene.truth, axis=-1).mean()
    error_after = np.linalg.norm(track.points - scene.truth, axis=-1).mean()
    assert error_after < 0.8 * error_before


def test_a_gap_is_bridged_with_an_uncertainty_growing_toward_its_middle():
    scene = walk(3)
    confidence = np.ones(scene.pixels.shape[:-1])
    gap = np.arange(60, 80)  # no camera sees the person for 0.4 s
    confidence[gap] = 0.0
    fusion = fused(scene, pixel_noise=2.0, seed=3, confidence=confidence)
    assert (fusion.provenance[gap] == Provenance.NONE).all()
    track = solve(fusion)
    assert np.isfinite(track.points).all() and (track.weight[gap] == 0).all()
    sigma = track.sigma.mean(-1)  # mean over joints, per frame
    inside = sigma[gap]
    middle = len(gap) // 2
    assert (np.diff(inside[:middle]) > 0).all() and (np.diff(inside[middle + 1 :]) < 0).all()
    assert inside.max() > 4 * np.median(sigma[:50])
    # The bridge is near the walk, within its own stated uncertainty on the whole.
    error = np.linalg.norm(track.points[gap] - scene.truth[gap], axis=-1)
    assert error.mean() < track.sigma[gap].mean()


def test_an_outlier_instant_is_down_weighted():
    scene = walk(4)
    fusion = fused(scene, pixel_noise=1.0, seed=4)
    frame, joint = 70, 6  # a foot put 300 mm off at one instant, with the evidence's usual confidence
    points = fusion.points.copy()
    points[frame, joint] += np.array([300.0, 0.0, 0.0])
    fusion = dataclasses.replace(fusion, points=points)
    robust = solve(fusion)
    plain = solve(fusion, dataclasses.replace(WALKING, robust_sigmas=1e9))
    assert robust.weight[frame, joint] < 0.05
    assert np.median(robust.weight) > 0.8
    robust_error = np.linalg.norm(robust.points[frame, joint] - scene.truth[frame, joint])
    plain_error = np.linalg.norm(plain.points[frame, joint] - scene.truth[frame, joint])
    assert robust_error < 5.0 and plain_error > 10 * robust_error


def test_limb_lengths_are_the_median_over_the_triangulated_instants():
    rng = np.random.default_rng(5)
    points = rng.normal(0, 300, (40, 3, 3))
    provenance = np.full((40, 3), Provenance.TRIANGULATED, np.int8)
    provenance[:15, 1] = Provenance.FUSED  # the fused instants are not measured while 10+ triangulated are
    bones = ((1, 0), (2, 1))
    lengths = limb_lengths(points, provenance, bones)
    expected = [np.median(np.linalg.norm(points[15:, 1] - points[15:, 0], axis=-1)),
                np.median(np.linalg.norm(points[15:, 2] - points[15:, 1], axis=-1))]  # fmt: skip
    np.testing.assert_allclose(lengths, expected)
    provenance[:35, 1] = Provenance.FUSED  # 5 triangulated instants: the fused ones count too
    np.testing.assert_allclose(limb_lengths(points, provenance, bones)[0], np.median(np.linalg.norm(points[:, 1] - points[:, 0], axis=-1)))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_banded_solve_is_the_dense_least_squares_minimum(seed):
    """A tiny problem (12 frames, a chain of 3 joints, random anisotropic covariances, a gap) against
    scipy's dense least squares of the same cost; without limbs, the sigmas against the dense inverse."""
    rng = np.random.default_rng(seed)
    F, J, bones = 12, 3, ((1, 0), (2, 1))
    truth = np.cumsum(rng.normal(0, 20, (F, J, 3)), 0) + np.array([0.0, 300.0, 600.0])[None, :, None]
    factor = rng.normal(0, 1, (F, J, 3, 3)) * rng.uniform(3, 30, (F, J, 1, 1))
    covariance = factor @ factor.swapaxes(-1, -2) + 4.0 * np.eye(3)
    points = truth + rng.normal(0, 10, truth.shape)
    provenance = np.full((F, J), Provenance.TRIANGULATED, np.int8)
    points[5:7, 2], covariance[5:7, 2], provenance[5:7, 2] = np.nan, np.nan, Provenance.NONE
    config = TrajectoryConfig(acceleration_mm_s2=20000.0, acceleration_dof=float("inf"), limb_sigma_mm=5.0, robust_sigmas=1e9, iterations=30)
    track = solve_trajectory(points, covariance, provenance, bones, FPS, config)
    lengths = limb_lengths(points, provenance, bones)
    has = provenance != Provenance.NONE
    whiten = np.linalg.cholesky(np.linalg.inv(covariance[has]))  # P = W W^T: residual W^T (x - y)
    q = config.acceleration_mm_s2 / FPS**2

    def residuals(flat, limb_sigma):
        x = flat.reshape(F, J, 3)
        evidence = np.einsum("nba,nb->na", whiten, x[has] - points[has]).ravel()
        motion = ((x[2:] - 2 * x[1:-1] + x[:-2]) / q).ravel()
        limbs = [(np.linalg.norm(x[:, c] - x[:, p], axis=-1) - lengths[b]) / limb_sigma for b, (c, p) in enumerate(bones)]
        return np.concatenate([evidence, motion, *limbs])

    start = np.where(has[..., None], points, truth).ravel()
    oracle = least_squares(residuals, start, args=(config.limb_sigma_mm,), method="lm", xtol=1e-14, ftol=1e-14, gtol=1e-14).x
    np.testing.assert_allclose(track.points, oracle.reshape(F, J, 3), atol=1e-3)

    free = dataclasses.replace(config, limb_sigma_mm=1e9)
    track = solve_trajectory(points, covariance, provenance, bones, FPS, free)
    oracle = least_squares(residuals, start, args=(free.limb_sigma_mm,), method="lm", xtol=1e-14, ftol=1e-14, gtol=1e-14)
    np.testing.assert_allclose(track.points, oracle.x.reshape(F, J, 3), atol=1e-3)
    covariance_oracle = np.linalg.inv(oracle.jac.T @ oracle.jac)  # the Gauss-Newton posterior, exact when linear
    sigma_oracle = np.sqrt(np.diagonal(covariance_oracle).reshape(F, J, 3).sum(-1))
    np.testing.assert_allclose(track.sigma, sigma_oracle, rtol=1e-4)


def test_a_joint_with_too_little_evidence_keeps_its_values():
    """A joint seen at one instant only (the prior fixes no line through one point) or never: its input
    values, no limb held to it; the others solved as without it."""
    scene = walk(6, frames=60)
    fusion = fused(scene, pixel_noise=1.0, seed=6)
    points, covariance = fusion.points.copy(), fusion.covariance.copy()
    points[1:, 3], covariance[1:, 3] = np.nan, np.nan  # RFoot: one instant
    points[:, 16], covariance[:, 16] = np.nan, np.nan  # RWrist: never
    provenance = np.where(np.isfinite(points).all(-1), fusion.provenance, Provenance.NONE)
    track = solve_trajectory(points, covariance, provenance, BONES, FPS, WALKING)
    np.testing.assert_array_equal(track.points[:, [3, 16]], points[:, [3, 16]].astype(np.float32))
    assert np.isnan(track.sigma[:, [3, 16]]).all() and np.isfinite(track.sigma[:, :3]).all()
    assert np.isnan(track.limb_lengths[[i for i, (c, _) in enumerate(BONES) if c in (3, 16)]]).all()
    error = np.linalg.norm(track.points[:, :3] - scene.truth[:, :3], axis=-1)
    assert error.mean() < np.linalg.norm(fusion.points[:, :3] - scene.truth[:, :3], axis=-1).mean()


@pytest.mark.parametrize("frames", [1, 2])
def test_a_recording_of_one_or_two_frames(frames):
    """No second difference to penalise: one frame is kept as it is (too little evidence), two come back
    as the evidence (every term 0 there, the limbs measured on no 10 instants)."""
    rng = np.random.default_rng(frames)
    points = rng.normal(0, 100, (frames, 3, 3))
    covariance = np.broadcast_to(25.0 * np.eye(3), (frames, 3, 3, 3))
    track = solve_trajectory(points, covariance, np.full((frames, 3), Provenance.TRIANGULATED), ((1, 0), (2, 1)), FPS)
    np.testing.assert_allclose(track.points, points, atol=1e-3)


def test_bad_shapes_and_settings_are_refused():
    with pytest.raises(ValueError, match="covariance"):
        solve_trajectory(np.zeros((5, 3, 3)), np.zeros((5, 3, 3)), np.zeros((5, 3)), (), FPS)
    with pytest.raises(ValueError, match="fps"):
        solve_trajectory(np.zeros((5, 3, 3)), np.zeros((5, 3, 3, 3)), np.zeros((5, 3)), (), 0.0)
    with pytest.raises(ValueError, match="acceleration_mm_s2"):
        TrajectoryConfig(acceleration_mm_s2=-1.0)


def test_a_recording_is_solved_apart_across_a_long_absence():
    """`smooth_recording`: the parts a gap longer than --max-gap separates are solved apart, each as alone
    (with the whole recording's limb lengths); a short gap is bridged, a long one left missing."""
    scene = walk(8, frames=120)
    confidence = np.ones(scene.pixels.shape[:-1])
    confidence[30:36] = 0.0  # 6 frames: bridged
    confidence[70:90] = 0.0  # 20 frames: the recording splits
    fusion = fused(scene, pixel_noise=1.0, seed=8, confidence=confidence)
    inputs = SimpleNamespace(name="walk", frames=np.arange(120), seen=(confidence > 0).any((1, 2)))
    motion = smooth_recording(inputs, fusion, BONES, FPS, WALKING, max_gap=10)
    assert (motion.provenance[30:36] == Provenance.INTERPOLATED).all() and np.isfinite(motion.points[30:36]).all()
    assert np.isnan(motion.points[70:90]).all() and np.isnan(motion.uncertainty[70:90]).all()
    np.testing.assert_array_equal(motion.segments, [[0, 70], [90, 120]])
    lengths = limb_lengths(fusion.points, fusion.provenance, BONES)
    for start, stop in motion.segments:
        part = slice(start, stop)
        alone = solve_trajectory(fusion.points[part], fusion.covariance[part], fusion.provenance[part], BONES, FPS, WALKING, lengths)
        np.testing.assert_allclose(motion.points[part], alone.points, atol=1e-4)


def run(seed: int, fps: float, seconds: float = 3.0) -> Walk:
    """A run: the simulated walk (~1 m/s) played 4 times as fast, ~4 m/s with accelerations of 40-60 m/s^2
    (median) to 230-290 m/s^2 (99th percentile; seed 0, at 30 and 120 fps), as seen at `fps`."""
    return walk(seed, frames=int(seconds * fps), fps=fps / 4.0)


def mpjpe(points: np.ndarray, truth: np.ndarray) -> float:
    return float(np.linalg.norm(points - truth, axis=-1).mean())


def test_a_fast_run_is_not_over_smoothed():
    """A 4 m/s run at 30 fps, 4 cameras, 3 px of detector noise: the default (the prior estimated from the
    recording) is at least as close to the truth as each instant alone (measured ~15% closer over 3 seeds),
    where one process noise chosen on slow motion (3000 mm/s^2) lags the legs by ~80 mm."""
    for seed in range(2):
        scene = run(seed, 30.0)
        fusion = fused(scene, pixel_noise=3.0, seed=seed)
        default = solve_trajectory(fusion.points, fusion.covariance, fusion.provenance, BONES, 30.0)
        slow = solve_trajectory(fusion.points, fusion.covariance, fusion.provenance, BONES, 30.0, TrajectoryConfig(acceleration_mm_s2=3000.0))
        per_instant = mpjpe(fusion.points, scene.truth)
        assert mpjpe(default.points, scene.truth) <= per_instant  # margin 0: the default must not lose
        assert mpjpe(slow.points, scene.truth) > 3 * per_instant


def test_the_estimated_noise_follows_the_motion():
    """The same body standing still, walking and running (30 fps, 3 px): each joint's estimate grows with the
    motion's accelerations, the run's median several times the walk's and the stand's; a given number is used as it is."""
    medians = {}
    for name, scene in (("stand", walk(0, frames=90, fps=30.0, rigid=True)), ("walk", walk(0, frames=90, fps=30.0)), ("run", run(0, 30.0))):
        if name == "stand":
            scene = dataclasses.replace(scene, truth=np.broadcast_to(scene.truth[:1], scene.truth.shape), pixels=np.broadcast_to(scene.pixels[:1], scene.pixels.shape))
        fusion = fused(scene, pixel_noise=3.0, seed=1)
        track = solve_trajectory(fusion.points, fusion.covariance, fusion.provenance, BONES, 30.0)
        assert track.acceleration_mm_s2.shape == (len(H36M_17.joint_names),)
        assert (track.acceleration_mm_s2 >= NOISE_GRID_MM_S2[0]).all() and (track.acceleration_mm_s2 <= NOISE_GRID_MM_S2[-1]).all()
        medians[name] = np.median(track.acceleration_mm_s2)
    assert medians["run"] > 4 * medians["walk"] and medians["walk"] > 4 * medians["stand"]
    fixed = solve_trajectory(fusion.points, fusion.covariance, fusion.provenance, BONES, 30.0, TrajectoryConfig(acceleration_mm_s2=5000.0))
    np.testing.assert_array_equal(fixed.acceleration_mm_s2, 5000.0)


def test_the_frame_rate_changes_the_noise_per_frame_not_per_second():
    """The same run seen at 30 and at 120 fps: the per-frame noise q / fps^2 differs 16-fold, the estimate in
    mm/s^2 by less than 2.5 (the 120 fps evidence holds sharper peaks that 30 fps averages out: on seed 0's
    run the truth's 99th-percentile acceleration is 290 m/s^2 at 120 fps against 230 at 30)."""
    estimates = []
    for fps in (30.0, 120.0):
        scene = run(2, fps, seconds=2.0)
        fusion = fused(scene, pixel_noise=3.0, seed=2)
        estimates.append(np.median(process_noise(fusion.points, fusion.covariance, fusion.provenance, fps)))
    assert 1 / 2.5 < estimates[1] / estimates[0] < 2.5


def test_the_estimate_maximises_the_dense_marginal_likelihood():
    """One joint's evidence of a random smooth path: `process_noise` against the log marginal likelihood
    written densely (y ~ N(0, K_q + S), the first two frames' prior N(0, kappa) with kappa -> large,
    its log kappa taken out) maximised by scipy over log q: within the parabola's refinement of the grid."""
    rng = np.random.default_rng(7)
    F, fps, sigma = 40, 30.0, 8.0
    truth = np.cumsum(np.cumsum(rng.normal(0, 20000.0 / fps**2, (F, 3)), 0), 0)
    covariance = np.broadcast_to(sigma**2 * np.eye(3), (F, 1, 3, 3))
    points = (truth + rng.normal(0, sigma, truth.shape))[:, None]
    estimate = process_noise(points, covariance, np.full((F, 1), Provenance.TRIANGULATED), fps)[0]
    kappa = 1e8
    build = np.zeros((F, F))  # L x = e: x0, x1 drawn freely, then each second difference
    build[0, 0] = build[1, 1] = 1.0
    for t in range(2, F):
        build[t, t - 2 : t + 1] = (1.0, -2.0, 1.0)
    inverse = np.linalg.inv(build)

    def negative_log_likelihood(log_q):
        variance = np.r_[kappa, kappa, np.full(F - 2, (np.exp(log_q) / fps**2) ** 2)]
        marginal = inverse @ np.diag(variance) @ inverse.T + sigma**2 * np.eye(F)
        _, log_determinant = np.linalg.slogdet(marginal)
        return 0.5 * sum(log_determinant + y @ np.linalg.solve(marginal, y) for y in points[:, 0].T) - 3 * np.log(kappa)

    from scipy.optimize import minimize_scalar

    best = minimize_scalar(negative_log_likelihood, bounds=(np.log(100.0), np.log(1e6)), method="bounded").x
    assert abs(np.log(estimate) - best) < 0.2


@pytest.mark.parametrize("fps", [1e5, 1e9])
def test_a_huge_frame_rate_gives_the_constant_velocity_fit(fps):
    """At --fps 1e5..1e9 the prior allows no acceleration over a short recording: the track is each joint's
    least-squares line through its evidence (the per-frame noise held at `MIN_NOISE_FRACTION` of the evidence's;
    before, the banded solve lost the evidence against the prior: every point 0, the pelvis wandering)."""
    rng = np.random.default_rng(3)
    F, J = 40, 3
    frames = np.arange(F)[:, None, None]
    line = rng.normal(0, 500, (1, J, 3)) + frames * rng.normal(0, 5, (1, J, 3))
    points = line + rng.normal(0, 10, (F, J, 3))
    covariance = np.broadcast_to(100.0 * np.eye(3), (F, J, 3, 3))
    for config in (TrajectoryConfig(robust_sigmas=1e9), TrajectoryConfig(acceleration_mm_s2=3000.0, robust_sigmas=1e9)):
        track = solve_trajectory(points, covariance, np.full((F, J), Provenance.TRIANGULATED), (), fps, config)
        design = np.c_[np.ones(F), np.arange(F)]
        coefficients = np.linalg.lstsq(design, points.reshape(F, -1), rcond=None)[0]
        np.testing.assert_allclose(track.points, (design @ coefficients).reshape(F, J, 3), atol=0.1)


def test_a_long_recording_is_solved_in_windows_as_a_whole_and_in_flat_memory(monkeypatch):
    """Windows of 100 frames with 60 of context (instead of 2000 and 400): the track of a 300-frame walk as
    one solve gives it, at fixed priors whose reach (a few frames) the context covers many times; and the
    peak memory of a recording 3 times as long grows by its arrays only (the solve's grew ~42 KB a frame of 17 joints)."""
    import tracemalloc

    from jaxpose.reconstruction import trajectory

    scene = walk(9, frames=300)
    fusion = fused(scene, pixel_noise=3.0, seed=9)
    for config in (WALKING, TrajectoryConfig(acceleration_mm_s2=3000.0)):
        monkeypatch.setattr(trajectory, "WINDOW_FRAMES", 10_000, raising=False)
        whole = solve(fusion, config)
        monkeypatch.setattr(trajectory, "WINDOW_FRAMES", 100, raising=False)
        monkeypatch.setattr(trajectory, "CONTEXT_FRAMES", 60, raising=False)
        windowed = solve(fusion, config)
        np.testing.assert_allclose(windowed.points, whole.points, atol=0.01)
        np.testing.assert_allclose(windowed.sigma, whole.sigma, rtol=1e-3)
    peaks = []
    for repeat in (1, 3):  # 300 and 900 frames of a leg (4 joints): windows of 220 frames
        points, covariance, provenance = (np.concatenate([value[:, :4]] * repeat) for value in (fusion.points, fusion.covariance, fusion.provenance))
        tracemalloc.start()
        solve_trajectory(points, covariance, provenance, BONES[:3], FPS, WALKING)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    # What still grows is the recording's own arrays (in, out: ~150 bytes a joint and frame); the solve grew ~2,400.
    assert (peaks[1] - peaks[0]) / (600 * 4) < 400
