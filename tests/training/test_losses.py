"""The four geometric losses: zero at the truth, growing under perturbation, finite gradients."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from geometry_helpers import LOSS_TERMS, exact_batch

from jaxpose import losses
from jaxpose.training.config import LossConfig
from jaxpose.losses import LossWeights, total_loss



def _perturbation(rng, shape, scale_mm):
    noise = jnp.asarray(rng.normal(0, scale_mm, shape), jnp.float32)
    return noise.at[..., 0, :].set(0.0)  # the lifter output keeps its root at zero


@pytest.mark.parametrize("name", sorted(LOSS_TERMS))
def test_loss_vanishes_at_truth_and_grows_under_perturbation(name):
    rng = np.random.default_rng(0)
    batch, truth = exact_batch(rng, 6, 4, 17)
    loss_fn = jax.jit(LOSS_TERMS[name])
    at_truth = float(loss_fn(truth, batch))
    perturbed = [float(loss_fn(truth + _perturbation(rng, truth.shape, s), batch)) for s in (10.0, 40.0)]
    assert at_truth < 1e-3 * perturbed[0], (at_truth, perturbed)
    assert perturbed[1] > perturbed[0] > 0
    gradient = jax.grad(loss_fn)(truth + _perturbation(rng, truth.shape, 10.0), batch)
    assert np.isfinite(np.asarray(gradient)).all() and float(jnp.abs(gradient).sum()) > 0


def test_output_triangulation_of_consistent_predictions_is_the_truth():
    rng = np.random.default_rng(1)
    batch, truth = exact_batch(rng, 4, 3, 16)
    np.testing.assert_allclose(jax.jit(losses.output_triangulation)(truth, batch), batch.pseudo3d, atol=0.1)


def test_consistency_gradient_flows_only_into_the_transformed_view():
    # View c is the target ("ground truth") for view c': with 2 views, perturbing view 0 changes
    # the gradient of view 0 only through the pair where view 0 is the source.
    rng = np.random.default_rng(2)
    batch, truth = exact_batch(rng, 2, 2, 15)
    pred = truth + _perturbation(rng, truth.shape, 20.0)
    gradient = jax.jit(jax.grad(losses.consistency_loss))(pred, batch)
    assert float(jnp.abs(gradient[:, 0]).sum()) > 0 and float(jnp.abs(gradient[:, 1]).sum()) > 0


def test_total_loss_is_the_weighted_sum_of_terms():
    rng = np.random.default_rng(3)
    batch, truth = exact_batch(rng, 4, 4, 17)
    pred = truth + _perturbation(rng, truth.shape, 25.0)
    weights = LossWeights(2.0, 0.5, 0.3, 0.7)
    loss, terms = jax.jit(total_loss)(pred, batch, weights)
    assert set(terms) == {"input_triangulation", "reprojection", "consistency", "output_triangulation"}
    expected = 2.0 * terms["input_triangulation"] + 0.5 * terms["reprojection"] + 0.3 * terms["consistency"]
    expected += 0.7 * terms["output_triangulation"]
    np.testing.assert_allclose(loss, expected, rtol=1e-6)
    each = jax.jit(lambda pred, batch: {name: fn(pred, batch) for name, fn in LOSS_TERMS.items()})(pred, batch)
    for name in LOSS_TERMS:
        np.testing.assert_allclose(terms[name], each[name], rtol=1e-5)


def test_input_triangulation_loss_matches_numpy_oracle():
    rng = np.random.default_rng(4)
    batch, truth = exact_batch(rng, 3, 4, 17)
    pred = truth + _perturbation(rng, truth.shape, 30.0)
    R, t = np.asarray(batch.cameras.R, np.float64), np.asarray(batch.cameras.t, np.float64)
    camera = np.einsum("bcij,bnj->bcni", R, np.asarray(batch.pseudo3d, np.float64)) + t[:, :, None]
    target = camera - camera[:, :, :1]
    squared = (((target - np.asarray(pred, np.float64)) / 1000.0) ** 2).sum(-1)[..., 1:]
    np.testing.assert_allclose(jax.jit(losses.input_triangulation_loss)(pred, batch), squared.mean(), rtol=1e-4)


@pytest.mark.parametrize("num_views", [2, 3, 4, 8])
@pytest.mark.parametrize("num_joints", [15, 16, 17])
def test_total_loss_jits_for_any_views_and_joints(num_views, num_joints):
    rng = np.random.default_rng(num_views * 100 + num_joints)
    batch, truth = exact_batch(rng, 2, num_views, num_joints)
    loss, terms = jax.jit(total_loss)(truth + _perturbation(rng, truth.shape, 10.0), batch, LossWeights())
    assert np.isfinite(float(loss)) and all(np.isfinite(float(v)) for v in terms.values())


def test_missing_joints_and_views_give_no_nan_and_are_ignored():
    rng = np.random.default_rng(5)
    batch, truth = exact_batch(rng, 4, 4, 17)
    pred = truth + _perturbation(rng, truth.shape, 15.0)
    confidence = batch.confidence.at[0, 1, 5].set(0.0).at[1, 2, :].set(0.0).at[2, 3, 0].set(0.0)
    # Garbage (NaN) where the detector reported nothing must not leak into any term or gradient.
    keypoints = jnp.where(confidence[..., None] > 0, batch.keypoints2d, jnp.nan)
    masked = batch.replace(confidence=confidence, keypoints2d=keypoints)
    value, grads = jax.jit(jax.value_and_grad(lambda p: total_loss(p, masked)[0]))(pred)
    assert np.isfinite(float(value)) and np.isfinite(np.asarray(grads)).all()
    # A joint whose pseudo-label weight is 0 teaches nothing through L_in.
    weight = jnp.ones(batch.pseudo3d.shape[:-1]).at[:, 7].set(0.0)
    untrusted = batch.replace(pseudo3d_weight=weight, pseudo3d=batch.pseudo3d.at[:, 7].add(1e4))
    gradient = jax.jit(jax.grad(losses.input_triangulation_loss))(pred, untrusted)
    assert float(jnp.abs(gradient[..., 7, :]).max()) == 0.0


def test_an_untrusted_root_silences_its_sample_in_the_input_triangulation_loss():
    rng = np.random.default_rng(6)
    batch, truth = exact_batch(rng, 3, 4, 17)
    pred = truth + _perturbation(rng, truth.shape, 15.0)
    weight = jnp.ones(batch.pseudo3d.shape[:-1]).at[1, 0].set(0.0)
    gradient = jax.jit(jax.grad(losses.input_triangulation_loss))(pred, batch.replace(pseudo3d_weight=weight))
    assert float(jnp.abs(gradient[1]).max()) == 0.0 and float(jnp.abs(gradient[0]).max()) > 0.0


def test_total_loss_accepts_a_numpy_batch_outside_jit():
    rng = np.random.default_rng(7)
    batch, truth = exact_batch(rng, 2, 3, 17)
    numpy_batch = jax.tree.map(np.asarray, batch)
    loss, _ = total_loss(np.asarray(truth), numpy_batch)
    assert float(loss) < 1e-3


def test_gradient_shares_match_the_norms_of_each_weighted_terms_gradient():
    rng = np.random.default_rng(5)
    batch, truth = exact_batch(rng, 5, 4, 17)
    pred = truth + _perturbation(rng, truth.shape, 30.0)
    weights = LossWeights(input_triangulation=1.0, reprojection=0.5, consistency=0.2, output_triangulation=0.0)
    shares = jax.jit(losses.gradient_shares)(pred, batch, weights)
    # Oracle: one jax.grad per term, then the norms normalised to sum to one.
    norms = {}
    for name in losses.TERMS:
        gradient = jax.jit(jax.grad(lambda p, n=name: getattr(weights, n) * losses.loss_terms(p, batch)[n]))(pred)
        norms[name] = float(jnp.linalg.norm(gradient))
    total = sum(norms.values())
    for name in losses.TERMS:
        np.testing.assert_allclose(float(shares[name]), norms[name] / total, rtol=1e-4, atol=1e-7)
    assert float(shares["output_triangulation"]) == 0.0  # weight 0: no share
    assert all(float(shares[name]) > 0.01 for name in losses.TERMS[:3])


def test_robust_label_penalty_is_squared_for_small_residuals_and_linear_for_gross_ones():
    rng = np.random.default_rng(6)
    batch, truth = exact_batch(rng, 4, 3, 16)
    small = truth + _perturbation(rng, truth.shape, 2.0)  # ~3 mm residuals, far below the 50 mm scale
    np.testing.assert_allclose(
        losses.input_triangulation_loss(small, batch, 50.0), losses.input_triangulation_loss(small, batch), rtol=2e-3
    )
    # One joint 1 m off in every view: the squared penalty grows with its square, the robust one
    # linearly, so a gross label error dominates the squared loss but not the robust one.
    gross = truth.at[:, :, 3, 0].add(1000.0)
    squared, robust = losses.input_triangulation_loss(gross, batch), losses.input_triangulation_loss(gross, batch, 50.0)
    per_joint_count = 15  # the root is excluded from the mean
    np.testing.assert_allclose(float(squared), 1.0 / per_joint_count, rtol=1e-4)  # (1 m)^2 on one joint of 15
    expected = 2 * 0.05**2 * (np.sqrt(1 + (1.0 / 0.05) ** 2) - 1) / per_joint_count
    np.testing.assert_allclose(float(robust), expected, rtol=1e-4)
    assert float(robust) < 0.15 * float(squared)


def test_loss_config_builds_the_weights_and_switches_l_out_on():
    config = LossConfig(input_triangulation=2.0, reprojection=0.5, consistency=0.25, output_triangulation=0.125)
    on, off = config.weights(True), config.weights(jnp.asarray(False))
    assert (on.input_triangulation, on.reprojection, on.consistency, float(on.output_triangulation)) == (2.0, 0.5, 0.25, 0.125)
    assert (off.input_triangulation, off.reprojection, off.consistency, float(off.output_triangulation)) == (2.0, 0.5, 0.25, 0.0)
