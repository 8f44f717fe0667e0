"""The 2D-to-3D lifter: a Martinez et al. (2017) style residual MLP in Flax Linen.

Paper text vs. the authors' code, and our choice:
- The paper (Sec. III-D) describes an encoder of one 1024-wide layer with four residual blocks and
  "a decoder with the same architecture".  The authors' release builds an encoder (2J -> 1024
  latent) and a decoder (latent -> 3J), EACH with 2 residual blocks of two Linear-BatchNorm-ReLU-
  Dropout(0.5) layers.  We default to the release (`stages=2, blocks_per_stage=2`), which is what
  the published numbers were produced with; `stages=1` gives Martinez's original network.
- Output: 3J numbers in metres (so the last layer starts at the right scale), returned in mm with
  the root row set to exactly zero, as the losses and metrics expect.

Linen rather than NNX because the train step is a pure function of a plain pytree state
(params, batch statistics, optimizer state), which is what `jax.jit` donation, sharding and Orbax
want; train/eval mode is an explicit argument, never hidden module state.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import linen as nn

MM_PER_M = 1000.0


def dropout_half(x: jax.Array, key: jax.Array) -> jax.Array:
    """Dropout at rate 0.5 from one random bit per element (inverted: survivors scaled by 2).

    `nn.Dropout` draws a float per element and compares it; at p = 0.5 a single bit decides, so we
    draw 32 bits per 32 elements.  The mask is a pure function of the key, like nn.Dropout's.
    """
    flat = x.reshape(-1)
    words = jax.random.bits(key, ((flat.shape[0] + 31) // 32,), dtype=jnp.uint32)
    bits = (words[:, None] >> jnp.arange(32, dtype=jnp.uint32)) & 1
    keep = bits.reshape(-1)[: flat.shape[0]].reshape(x.shape).astype(bool)
    return jnp.where(keep, x * 2.0, 0.0)


class DenseBlock(nn.Module):
    """Linear -> BatchNorm -> ReLU -> Dropout."""

    width: int
    dropout_rate: float
    use_batchnorm: bool

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> jax.Array:
        x = nn.Dense(self.width, kernel_init=nn.initializers.he_normal(), use_bias=not self.use_batchnorm)(x)
        if self.use_batchnorm:
            # momentum 0.9 = PyTorch's 0.1 update rate, as in the reference implementations.
            x = nn.BatchNorm(use_running_average=not train, momentum=0.9, epsilon=1e-5)(x)
        x = nn.relu(x)
        if train and self.dropout_rate > 0:
            key = self.make_rng("dropout")
            if self.dropout_rate == 0.5:
                x = dropout_half(x, key)
            else:
                x = nn.Dropout(self.dropout_rate, deterministic=False)(x, rng=key)
        return x


class ResidualBlock(nn.Module):
    """x + (DenseBlock -> DenseBlock)(x)."""

    width: int
    dropout_rate: float
    use_batchnorm: bool

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> jax.Array:
        y = DenseBlock(self.width, self.dropout_rate, self.use_batchnorm)(x, train)
        y = DenseBlock(self.width, self.dropout_rate, self.use_batchnorm)(y, train)
        return x + y


class Lifter(nn.Module):
    """Root-relative 2D pose (normalized, [..., J, 2]) -> root-relative 3D pose in mm [..., J, 3].

    Each stage is a DenseBlock to `width` followed by `blocks_per_stage` residual blocks; the
    encoder is stage 1 (its output the latent), the decoder the remaining stages, then a Linear
    layer to 3J.
    """

    num_joints: int
    width: int = 1024
    stages: int = 2
    blocks_per_stage: int = 2
    dropout_rate: float = 0.5
    use_batchnorm: bool = True

    @nn.compact
    def __call__(self, keypoints: jax.Array, train: bool) -> jax.Array:
        if keypoints.shape[-2:] != (self.num_joints, 2):
            raise ValueError(f"Lifter: expected inputs [..., {self.num_joints}, 2], got {keypoints.shape}")
        leading = keypoints.shape[:-2]
        x = keypoints.reshape(-1, self.num_joints * 2)
        for _ in range(self.stages):
            x = DenseBlock(self.width, self.dropout_rate, self.use_batchnorm)(x, train)
            for _ in range(self.blocks_per_stage):
                x = ResidualBlock(self.width, self.dropout_rate, self.use_batchnorm)(x, train)
        # A small initial output (~cm) instead of metres: early predictions stay in front of the
        # cameras, so the projection-based losses start with sane values and gradients.
        x = nn.Dense(self.num_joints * 3, kernel_init=nn.initializers.variance_scaling(1e-3, "fan_in", "normal"))(x)
        pose = x.reshape(*leading, self.num_joints, 3) * MM_PER_M
        return pose.at[..., 0, :].set(0.0)
