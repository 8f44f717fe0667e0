"""The jitted train step: one compile, a working optimizer, and single-view prediction."""

import chex
import jax
import numpy as np
import pytest
from geometry_helpers import exact_batch

from jaxpose.training.config import LossConfig, OptimizerConfig
from jaxpose.model import ModelConfig
from jaxpose.model import make_eval_step
from jaxpose.training.step import (
    init_train_state,
    jit_train_step,
    make_train_step,
)

SMALL = ModelConfig(width=64, dropout_rate=0.5)


def _setup(model_config, loss_config, total_steps, num_joints=17):
    model = model_config.build(num_joints)
    optimizer = OptimizerConfig().build(total_steps)
    state = init_train_state(model, optimizer, jax.random.key(0))
    step = make_train_step(model, model_config, optimizer, loss_config, total_steps)
    return model, state, step


def test_train_step_compiles_once_across_the_output_triangulation_switch():
    batch, _ = exact_batch(np.random.default_rng(0), 8, 4, 17)
    # 6 steps, L_out on from step 3: the switch happens inside the traced computation.
    _, state, step = _setup(SMALL, LossConfig(output_triangulation_start=0.5), total_steps=6)
    counted = jax.jit(chex.assert_max_traces(step, n=1), donate_argnums=0)
    weights = []
    for _ in range(6):
        state, metrics = counted(state, batch, jax.random.key(1))
        weights.append(float(metrics["output_triangulation_weight"]))
    np.testing.assert_allclose(weights, [0.0, 0.0, 0.0, 0.01, 0.01, 0.01])
    assert counted._cache_size() == 1
    assert int(state.step) == 6


def test_gradient_shares_are_measured_where_asked_by_one_program_and_change_nothing_else():
    batch, _ = exact_batch(np.random.default_rng(3), 8, 4, 17)
    model = SMALL.build(17)
    optimizer = OptimizerConfig().build(7)
    step = make_train_step(model, SMALL, optimizer, LossConfig(output_triangulation_start=0.0), 7)
    counted = jax.jit(chex.assert_max_traces(step, n=1))
    # The loop asks on the steps it logs (here the 3rd and the 5th); both switch values run one compiled program.
    asked = [False, False, True, False, True]
    measured = state = init_train_state(model, optimizer, jax.random.key(0))
    sums = []
    for measure in asked:
        measured, metrics = counted(measured, batch, jax.random.key(1), measure)
        sums.append(sum(float(value) for name, value in metrics.items() if name.startswith("grad_share_")))
        state, _ = counted(state, batch, jax.random.key(1), False)
    np.testing.assert_allclose(sums, [1.0 if measure else 0.0 for measure in asked], atol=1e-5)
    assert counted._cache_size() == 1
    # Measuring is a side computation: the training itself is bit for bit that of a run that never measures.
    chex.assert_trees_all_equal(measured, state)


def test_train_step_reduces_the_loss_tenfold_on_a_fixed_batch():
    # The optimization machinery (gradients through all four losses, Adam, BatchNorm) on one fixed
    # batch; dropout off so that memorizing unstructured random poses is possible at all.
    batch, _ = exact_batch(np.random.default_rng(1), 32, 4, 17)
    # 100 steps: the loss falls about a hundredfold (300 steps were no surer; the compilation is most of the cost).
    _, state, step = _setup(ModelConfig(width=256, dropout_rate=0.0), LossConfig(output_triangulation_start=0.0), 100)
    step = jit_train_step(step)
    losses = []
    for _ in range(100):
        state, metrics = step(state, batch, jax.random.key(2), False)
        losses.append(float(metrics["loss"]))
    assert np.isfinite(losses).all()
    assert np.mean(losses[-10:]) < np.mean(losses[:3]) / 10, (losses[:3], losses[-10:])


def test_supervised_mode_reads_the_ground_truth_and_needs_it():
    batch, _ = exact_batch(np.random.default_rng(2), 8, 3, 16)
    _, state, step = _setup(SMALL, LossConfig(supervision="full"), 10, num_joints=16)
    state, metrics = jax.jit(step)(state, batch, jax.random.key(0))
    assert "supervised" in metrics and np.isfinite(float(metrics["loss"]))
    with pytest.raises(ValueError, match="target3d"):
        step(state, batch.replace(target3d=None), jax.random.key(0))


def test_dropout_masks_depend_on_the_step_and_are_reproducible():
    batch, _ = exact_batch(np.random.default_rng(3), 8, 4, 17)
    _, state, step = _setup(SMALL, LossConfig(), 10)
    step = jax.jit(step)
    a, _ = step(state, batch, jax.random.key(5))
    b, _ = step(state, batch, jax.random.key(5))
    chex.assert_trees_all_equal(a.params, b.params)


def test_predict_is_single_view_and_root_relative():
    batch, _ = exact_batch(np.random.default_rng(4), 8, 4, 17)
    model, state, _ = _setup(SMALL, LossConfig(), 10)
    predict = make_eval_step(model, SMALL)
    pose = predict(state.variables, batch.keypoints2d[:, 0], batch.cameras.K[:, 0], batch.confidence[:, 0])
    assert pose.shape == (8, 17, 3)
    assert np.all(np.asarray(pose[:, 0]) == 0.0)
    # Eval mode is deterministic and per-sample (BatchNorm uses running statistics).
    one = predict(state.variables, batch.keypoints2d[:1, 0], batch.cameras.K[:1, 0], batch.confidence[:1, 0])
    np.testing.assert_allclose(one[0], pose[0], atol=1e-3)
