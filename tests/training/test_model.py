"""The fused BatchNorm -> ReLU -> dropout layer equals Flax's BatchNorm, ReLU and a masked dropout."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import linen as nn

from jaxpose.model import BatchNormReLUDropout, dropout_keep_mask


class _Reference(nn.Module):
    keep_scale: float

    @nn.compact
    def __call__(self, y, keep, train=True):
        x = nn.relu(nn.BatchNorm(use_running_average=not train, momentum=0.9, epsilon=1e-5, name="BatchNorm_0")(y))
        return x if keep is None else jnp.where(keep, self.keep_scale * x, 0.0)


class _Fused(nn.Module):
    keep_scale: float

    @nn.compact
    def __call__(self, y, keep, train=True):
        return BatchNormReLUDropout(self.keep_scale, name="BatchNorm_0")(y, keep, train)


@pytest.mark.parametrize("rate", [0.0, 0.5, 0.2])
def test_fused_layer_matches_flax_batchnorm_relu_dropout(rate):
    rng = np.random.default_rng(0)
    y = jnp.asarray(rng.normal(1.0, 3.0, (256, 64)), jnp.float32)
    cotangent = jnp.asarray(rng.normal(size=(256, 64)), jnp.float32)
    keep = dropout_keep_mask(jax.random.key(1), y.shape, rate) if rate else None
    keep_scale = 1.0 / (1.0 - rate)
    reference, fused = _Reference(keep_scale), _Fused(keep_scale)
    variables = reference.init(jax.random.key(0), y, keep)
    params = {"BatchNorm_0": {"scale": jnp.linspace(0.5, 1.5, 64), "bias": jnp.linspace(-0.2, 0.2, 64)}}
    variables = {"params": params, "batch_stats": variables["batch_stats"]}
    assert jax.tree.structure(fused.init(jax.random.key(0), y, keep)) == jax.tree.structure(variables)

    def loss(module, params, y):
        out, updates = module.apply({**variables, "params": params}, y, keep, mutable=["batch_stats"])
        return jnp.vdot(out, cotangent), (out, updates)

    results = [jax.jit(jax.value_and_grad(lambda p, y, m=m: loss(m, p, y), (0, 1), has_aux=True))(params, y) for m in (reference, fused)]
    (_, (out_ref, stats_ref)), grads_ref = results[0]
    (_, (out, stats)), grads = results[1]
    np.testing.assert_allclose(out, out_ref, rtol=1e-5, atol=1e-5)
    for a, b in zip(jax.tree.leaves((stats, grads)), jax.tree.leaves((stats_ref, grads_ref))):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-4 * float(jnp.abs(b).max()))
    # Eval mode: the running statistics, no dropout.
    trained = {"params": params, "batch_stats": stats["batch_stats"]}
    np.testing.assert_allclose(fused.apply(trained, y, None, False), reference.apply(trained, y, None, False), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("rate,shape", [(0.5, (500, 200)), (0.5, (333, 7)), (0.2, (500, 200))])
def test_dropout_keep_mask_rate_and_determinism(rate, shape):
    keep = dropout_keep_mask(jax.random.key(3), shape, rate)
    tolerance = 4 * np.sqrt(rate * (1 - rate) / np.prod(shape))
    assert keep.dtype == bool and keep.shape == shape and abs(float(keep.mean()) - (1 - rate)) < tolerance
    np.testing.assert_array_equal(keep, dropout_keep_mask(jax.random.key(3), shape, rate))
    assert not np.array_equal(keep, dropout_keep_mask(jax.random.key(4), shape, rate))
