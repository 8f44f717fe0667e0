"""Train-time mirroring (`InputAugmentation.mirror`, `jaxpose.training.step.mirror_views`): a view lifted from its
mirror image and its lift mirrored back leaves the losses of a mirror-equivariant lifter exactly as they
were, changes those of any other, is drawn with its probability, and costs no recompilation."""

import chex
import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from geometry_helpers import exact_batch

from jaxpose.training.config import InputAugmentation, LossConfig, OptimizerConfig
from jaxpose.model import ModelConfig
from jaxpose.flip import mirror_input
from jaxpose.skeleton import H36M_17
from jaxpose.training.step import init_train_state, make_loss_fn, make_train_step, mirror_views

MIRROR = InputAugmentation(mirror=1.0)
CONFIG = ModelConfig(width=64, dropout_rate=0.0)  # its input normalisation: the default median scale


class EquivariantLifter(nn.Module):
    """Joint j at s * (x_j, y_j, a (x_j^2 + y_j^2)) of its normalised 2D (a window's centre frame): the
    mirror image's lift, mirrored back, is exactly the plain lift."""

    @nn.compact
    def __call__(self, inputs: jax.Array, train: bool) -> jax.Array:
        scale = self.param("scale", lambda _: jnp.asarray(900.0))
        depth = self.param("depth", lambda _: jnp.asarray(0.7))
        xy = inputs[..., inputs.shape[-3] // 2, :, :] if inputs.ndim == 5 else inputs
        return scale * jnp.concatenate([xy, depth * (xy**2).sum(-1, keepdims=True)], -1)


def with_window(batch, frames: int = 3):
    """The batch with a window of `frames` jittered copies of every view's pose (the centre one as given)."""
    jitter = 3.0 * jax.random.normal(jax.random.key(9), batch.keypoints2d.shape[:2] + (frames,) + batch.keypoints2d.shape[2:])
    window = batch.keypoints2d[:, :, None] + jitter.at[:, :, frames // 2].set(0.0)
    return batch.replace(window2d=window, window_confidence=jnp.broadcast_to(batch.confidence[:, :, None], window.shape[:-1]))


def losses(model, variables, batch, augmentation, supervision="self"):
    loss = LossConfig(output_triangulation_start=0.0, supervision=supervision)
    loss_fn = make_loss_fn(model, CONFIG, loss, 0, augmentation=augmentation, skeleton=H36M_17)
    value, (metrics, _) = jax.jit(loss_fn)(variables["params"], variables.get("batch_stats", {}), batch, jax.random.key(3), 0, True)
    return float(value), {name: float(metric) for name, metric in metrics.items()}


@pytest.mark.parametrize("supervision, window", [("self", False), ("self", True), ("full", False)])
def test_an_equivariant_lifter_loses_exactly_what_it_lost_unmirrored(supervision, window):
    batch, _ = exact_batch(np.random.default_rng(0), 8, 4, 17)
    batch = with_window(batch) if window else batch
    model = EquivariantLifter()
    variables = model.init(jax.random.key(0), batch.keypoints2d, train=False)
    plain, plain_metrics = losses(model, variables, batch, InputAugmentation(), supervision)
    mirrored, mirrored_metrics = losses(model, variables, batch, MIRROR, supervision)
    assert plain > 1e-3  # the toy lifter is far from the truth: there is a loss to compare
    np.testing.assert_allclose(mirrored, plain, rtol=1e-5)
    for name, value in plain_metrics.items():
        np.testing.assert_allclose(mirrored_metrics[name], value, rtol=1e-4, atol=1e-7, err_msg=name)


def test_a_random_lifter_lifts_its_mirror_images_differently():
    batch, _ = exact_batch(np.random.default_rng(1), 8, 4, 17)
    model = CONFIG.build(17)
    variables = model.init(jax.random.key(1), jnp.zeros(model.input_shape(2)), train=False)
    # Weights far from their initialisation, so that the lift, not the pseudo-labels' size, makes the loss.
    variables = {"params": jax.tree.map(lambda v: v + 0.3 * jax.random.normal(jax.random.key(2), v.shape), variables["params"])}
    plain, _ = losses(model, variables, batch, InputAugmentation())
    assert abs(losses(model, variables, batch, MIRROR)[0] - plain) > 0.05 * plain


def test_views_are_mirrored_with_their_probability_and_reproducibly():
    batch, _ = exact_batch(np.random.default_rng(2), 8, 4, 17)
    B, C = 512, 4  # 2,048 views: a fraction of 0.3 within 0.03 is 3 standard deviations
    keypoints = jnp.tile(batch.keypoints2d, (B // 8, 1, 1, 1))
    K, confidence = jnp.tile(batch.cameras.K, (B // 8, 1, 1, 1)), jnp.tile(batch.confidence, (B // 8, 1, 1))
    *views, mirrored = mirror_views(jax.random.key(4), keypoints, K, confidence, 0.3, H36M_17)
    mirrored = np.asarray(mirrored)
    assert mirrored.shape == (B, C) and abs(mirrored.mean() - 0.3) < 0.03
    mirror_image = mirror_input(keypoints, K, confidence, H36M_17)
    for view, given, image in zip(views, (keypoints, K, confidence), mirror_image):
        np.testing.assert_array_equal(np.asarray(view)[mirrored], np.asarray(image)[mirrored])
        np.testing.assert_array_equal(np.asarray(view)[~mirrored], np.asarray(given)[~mirrored])
    again = mirror_views(jax.random.key(4), keypoints, K, confidence, 0.3, H36M_17)[-1]
    np.testing.assert_array_equal(np.asarray(again), mirrored)
    assert not np.array_equal(np.asarray(mirror_views(jax.random.key(5), keypoints, K, confidence, 0.3, H36M_17)[-1]), mirrored)
    with pytest.raises(ValueError, match="mirror"):
        InputAugmentation(mirror=1.5)


def test_the_mirroring_train_step_compiles_once_and_resumes_bit_identically():
    batch, _ = exact_batch(np.random.default_rng(3), 8, 4, 17)
    model = ModelConfig(width=64, dropout_rate=0.2).build(17)
    optimizer = OptimizerConfig().build(6)
    augmentation = InputAugmentation(drop=0.1, mirror=0.5)
    step = make_train_step(model, CONFIG, optimizer, LossConfig(output_triangulation_start=0.5), 6, augmentation=augmentation, skeleton=H36M_17)
    counted = jax.jit(chex.assert_max_traces(step, n=1))
    state = init_train_state(model, optimizer, jax.random.key(0))
    states = [state]
    for _ in range(6):  # across the output triangulation's switch, each step its own draws
        state, _ = counted(state, batch, jax.random.key(1))
        states.append(state)
    assert counted._cache_size() == 1
    resumed = jax.jit(step)  # a resumed run: a new process compiles the step again and starts at step 3
    state = states[3]
    for _ in range(3):
        state, _ = resumed(state, batch, jax.random.key(1))
    chex.assert_trees_all_equal(state.params, states[6].params)
    with pytest.raises(ValueError, match="skeleton"):
        make_train_step(model, CONFIG, optimizer, LossConfig(), 6, augmentation=augmentation)
