"""The 2D-to-3D lifter: a Martinez et al. (2017) style residual MLP in Flax Linen.

Paper text vs. the authors' code, and our choice:
- The paper (Sec. III-D) describes an encoder of one 1024-wide layer with four residual blocks and
  "a decoder with the same architecture".  The authors' release builds an encoder (2J -> 1024
  latent) and a decoder (latent -> 3J), EACH with 2 residual blocks of two Linear-BatchNorm-ReLU-
  Dropout(0.5) layers.  We default to the release (`stages=2, blocks_per_stage=2`), which is what
  the published numbers were produced with; `stages=1` gives Martinez's original network.
- Output: 3J numbers in metres (so the last layer starts at the right scale), returned in mm with
  the root row set to exactly zero, as the losses and metrics expect.
- Speed: each hidden layer's BatchNorm, ReLU and dropout are one op with a hand-written gradient
  (`batch_norm_relu_dropout`); variables, statistics and masks are those of Flax's BatchNorm and
  of dropout with the same key, so the network computes what the plain composition computes.

Linen rather than NNX because the train step is a pure function of a plain pytree state
(params, batch statistics, optimizer state), which is what `jax.jit` donation, sharding and Orbax
want; train/eval mode is an explicit argument, never hidden module state.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from typing import Literal

import jax
import jax.numpy as jnp
from flax import linen as nn

from jaxpose.camera import MM_PER_M, normalize_keypoints


def dropout_keep_mask(key: jax.Array, shape: tuple[int, ...], rate: float) -> jax.Array:
    """bool mask of the elements that dropout at `rate` keeps, a pure function of the key.

    At rate 0.5 one random bit decides, so we draw 32 bits per 32 elements (nn.Dropout draws and
    compares a float per element); other rates draw a Bernoulli variable per element.
    """
    if rate != 0.5:
        return jax.random.bernoulli(key, 1.0 - rate, shape)
    size = math.prod(shape)
    words = jax.random.bits(key, ((size + 31) // 32,), dtype=jnp.uint32)
    bits = (words[:, None] >> jnp.arange(32, dtype=jnp.uint32)) & 1
    return bits.reshape(-1)[:size].reshape(shape).astype(bool)


def _batch_statistics(y: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Mean and biased variance over the batch axis from E[y] and E[y^2], as Flax's BatchNorm
    computes them (`use_fast_variance`)."""
    mean = jnp.mean(y, axis=0)
    return mean, jnp.maximum(jnp.mean(jnp.square(y), axis=0) - jnp.square(mean), 0.0)


def _affine(mean: jax.Array, var: jax.Array, scale: jax.Array, bias: jax.Array, epsilon: float):
    """BatchNorm as y * a + c: one multiply-add per element instead of subtract, scale, shift."""
    rstd = jax.lax.rsqrt(var + epsilon)
    a = scale * rstd
    return a, bias - mean * a, rstd


@functools.partial(jax.custom_vjp, nondiff_argnums=(4, 5))
def batch_norm_relu_dropout(
    y: jax.Array, scale: jax.Array, bias: jax.Array, keep: jax.Array | None, keep_scale: float, epsilon: float
) -> jax.Array:
    """Training-mode BatchNorm (batch statistics) -> ReLU -> dropout, y [N, F] -> [N, F].

    `keep` (bool [N, F], or None for no dropout) is the dropout mask; survivors are multiplied by
    `keep_scale`.  The composition of the three layers with a hand-written gradient: autodiff of
    the composition makes XLA save and traverse several more [N, F] intermediates, while the
    backward pass needs only y and the mask (one pass for the two gradient sums, one for dy).
    At the paper's batch these elementwise passes over 32768 x 1024 activations, and the fresh
    buffers they fill, are most of what the train step spends outside its matrix products.
    """
    return _batch_norm_relu_dropout_forward(y, scale, bias, keep, keep_scale, epsilon)[0]


def _active(pre: jax.Array, keep: jax.Array | None) -> jax.Array:
    """Where the output is the (scaled) BatchNorm output: ReLU passes it and dropout keeps it."""
    return pre > 0 if keep is None else keep & (pre > 0)


def _batch_norm_relu_dropout_forward(y, scale, bias, keep, keep_scale, epsilon):
    mean, var = _batch_statistics(y)
    a, c, rstd = _affine(mean, var, scale, bias, epsilon)
    pre = y * a + c
    out = jnp.where(_active(pre, keep), keep_scale * pre, 0.0)
    return out, (y, keep, scale, mean, rstd, a, c)


def _batch_norm_relu_dropout_backward(keep_scale, epsilon, residuals, d_out):
    y, keep, scale, mean, rstd, a, c = residuals
    # Gradient at the BatchNorm output (ReLU and dropout are masks), then the BatchNorm
    # backward: d_bias = sum(d_pre), d_scale = sum(d_pre * x_hat) with x_hat = (y - mean) * rstd,
    # dy = a * (d_pre - mean(d_pre) - x_hat * mean(d_pre * x_hat)).
    d_pre = jnp.where(_active(y * a + c, keep), keep_scale * d_out, 0.0)
    d_bias = jnp.sum(d_pre, axis=0)
    d_scale = rstd * (jnp.sum(d_pre * y, axis=0) - mean * d_bias)
    count = y.shape[0]
    dy = a * (d_pre - d_bias / count) - (a * rstd * d_scale / count) * (y - mean)
    return dy, d_scale.astype(scale.dtype), d_bias.astype(scale.dtype), None


batch_norm_relu_dropout.defvjp(_batch_norm_relu_dropout_forward, _batch_norm_relu_dropout_backward)


class BatchNormReLUDropout(nn.Module):
    """BatchNorm -> ReLU -> dropout over [N, F], with the variables of `nn.BatchNorm`.

    params `scale`, `bias` and batch_stats `mean`, `var` (running averages of the biased batch
    variance with `momentum`), initialized as in Flax, so checkpoints of either module load into
    the other.  `keep` is the dropout mask (None: no dropout); survivors are scaled by `keep_scale`.
    """

    keep_scale: float = 1.0
    momentum: float = 0.9
    epsilon: float = 1e-5

    @nn.compact
    def __call__(self, y: jax.Array, keep: jax.Array | None, train: bool) -> jax.Array:
        features = y.shape[-1]
        scale = self.param("scale", nn.initializers.ones, (features,), jnp.float32)
        bias = self.param("bias", nn.initializers.zeros, (features,), jnp.float32)
        ra_mean = self.variable("batch_stats", "mean", jnp.zeros, (features,), jnp.float32)
        ra_var = self.variable("batch_stats", "var", jnp.ones, (features,), jnp.float32)
        if not train:
            a, c, _ = _affine(ra_mean.value, ra_var.value, scale, bias, self.epsilon)
            return jax.nn.relu(y * a + c)
        if not self.is_initializing():
            # The same reductions as inside batch_norm_relu_dropout: XLA computes them once.
            mean, var = jax.lax.stop_gradient(_batch_statistics(y))
            ra_mean.value = self.momentum * ra_mean.value + (1 - self.momentum) * mean
            ra_var.value = self.momentum * ra_var.value + (1 - self.momentum) * var
        return batch_norm_relu_dropout(y, scale, bias, keep, self.keep_scale, self.epsilon)


class DenseBlock(nn.Module):
    """Linear -> BatchNorm -> ReLU -> Dropout."""

    width: int
    dropout_rate: float
    use_batchnorm: bool

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> jax.Array:
        x = nn.Dense(self.width, kernel_init=nn.initializers.he_normal(), use_bias=not self.use_batchnorm)(x)
        if not 0.0 <= self.dropout_rate < 1.0:
            raise ValueError(f"dropout_rate must lie in [0, 1), got {self.dropout_rate}")
        keep = None
        if train and self.dropout_rate > 0:
            keep = dropout_keep_mask(self.make_rng("dropout"), x.shape, self.dropout_rate)
        keep_scale = 1.0 / (1.0 - self.dropout_rate)
        if self.use_batchnorm:
            # momentum 0.9 = PyTorch's 0.1 update rate, as in the reference implementations.  Named
            # as the nn.BatchNorm it replaces, so that the variable tree is unchanged.
            return BatchNormReLUDropout(keep_scale, momentum=0.9, epsilon=1e-5, name="BatchNorm_0")(x, keep, train)
        x = nn.relu(x)
        return x if keep is None else jnp.where(keep, keep_scale * x, 0.0)


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


def temporal_levels(window: int) -> int:
    """L for a window of 3^L frames (1, 3, 9, 27, 81, 243); ValueError otherwise."""
    levels = 0
    while 3**levels < window:
        levels += 1
    if window < 1 or 3**levels != window:
        raise ValueError(f"temporal window must be a power of 3 (1, 3, 9, 27, 81, 243), got {window}")
    return levels


def _rows(block: nn.Module, x: jax.Array, train: bool) -> jax.Array:
    """Apply a [rows, F] block to [M, T, F] (BatchNorm statistics over all M * T rows)."""
    M, T, F = x.shape
    return block(x.reshape(M * T, F), train).reshape(M, T, -1)


def _group_triples(x: jax.Array) -> jax.Array:
    """[M, T, F] -> [M, T / 3, 3F]: each run of three consecutive frames as one row.  A Dense layer on
    these rows is a temporal convolution of kernel 3 and stride 3: evaluated only where the window's
    centre output needs it, it is the dilated convolution of VideoPose3D (dilation 3^level)."""
    M, T, F = x.shape
    return x.reshape(M, T // 3, 3 * F)


class TemporalBlock(nn.Module):
    """VideoPose3D's residual block on frame triples: the centre frame of each triple plus
    (kernel-3 convolution -> kernel-1 convolution), each Linear-BatchNorm-ReLU-Dropout."""

    width: int
    dropout_rate: float
    use_batchnorm: bool

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> jax.Array:
        y = _rows(DenseBlock(self.width, self.dropout_rate, self.use_batchnorm), _group_triples(x), train)
        y = _rows(DenseBlock(self.width, self.dropout_rate, self.use_batchnorm), y, train)
        return x[:, 1::3] + y


class LifterNetwork(nn.Module):
    """Root-relative 2D pose (normalized, [..., J, 2]) -> root-relative 3D pose in mm [..., J, 3];
    with `temporal_window` T > 1, a window of T consecutive frames of one view [..., T, J, 2] -> the
    centre frame's 3D pose [..., J, 3].

    Each stage is a DenseBlock to `width` followed by `blocks_per_stage` residual blocks; the
    encoder is stage 1 (its output the latent), the decoder the remaining stages, then a Linear
    layer to 3J.  With T = 3^L frames, stage 1's first DenseBlock takes the frames in triples and
    L - 1 `TemporalBlock`s reduce the window to one row before the rest of the network: VideoPose3D's
    dilated temporal convolutions (Pavllo et al. 2019), evaluated at the centre frame only.  T = 1 is
    exactly the frame network (same variables, same function).
    """

    num_joints: int
    width: int = 1024
    stages: int = 2
    blocks_per_stage: int = 2
    dropout_rate: float = 0.5
    use_batchnorm: bool = True
    temporal_window: int = 1

    def input_shape(self, batch: int) -> tuple[int, ...]:
        """The input of `batch` poses: (batch, J, 2), or (batch, T, J, 2) for a window of T frames."""
        window = () if self.temporal_window == 1 else (self.temporal_window,)
        return (batch, *window, self.num_joints, 2)

    @nn.compact
    def __call__(self, keypoints: jax.Array, train: bool) -> jax.Array:
        T = self.temporal_window
        levels = temporal_levels(T)
        frame = (self.num_joints, 2) if T == 1 else (T, self.num_joints, 2)
        if keypoints.shape[-len(frame) :] != frame:
            shape = ", ".join(map(str, frame))
            raise ValueError(f"LifterNetwork: expected inputs [..., {shape}], got {keypoints.shape}")
        leading = keypoints.shape[: keypoints.ndim - len(frame)]
        x = keypoints.reshape(-1, T, self.num_joints * 2)
        x = _rows(DenseBlock(self.width, self.dropout_rate, self.use_batchnorm), _group_triples(x) if levels else x, train)
        for level in range(1, levels):
            x = TemporalBlock(self.width, self.dropout_rate, self.use_batchnorm, name=f"TemporalBlock_{level}")(x, train)
        x = x[:, 0]
        for stage in range(self.stages):
            if stage > 0:
                x = DenseBlock(self.width, self.dropout_rate, self.use_batchnorm)(x, train)
            for _ in range(self.blocks_per_stage):
                x = ResidualBlock(self.width, self.dropout_rate, self.use_batchnorm)(x, train)
        # A small initial output (~cm) instead of metres: early predictions stay in front of the
        # cameras, so the projection-based losses start with sane values and gradients.
        x = nn.Dense(self.num_joints * 3, kernel_init=nn.initializers.variance_scaling(1e-3, "fan_in", "normal"))(x)
        pose = x.reshape(*leading, self.num_joints, 3) * MM_PER_M
        return pose.at[..., 0, :].set(0.0)


def normalize_views(keypoints2d: jax.Array, K: jax.Array, confidence: jax.Array, mode: str) -> jax.Array:
    """`normalize_keypoints` of poses [N..., J, 2] or windows [N..., T, J, 2] of views whose intrinsics
    are K [N..., 3, 3]: every frame of a window is normalized on its own, as the frame lifter's input."""
    K = K.reshape(K.shape[:-2] + (1,) * (confidence.ndim - 1 - (K.ndim - 2)) + K.shape[-2:])
    return normalize_keypoints(keypoints2d, K, confidence, mode)


@dataclasses.dataclass(frozen=True)
class ModelConfig:
    """The lifter (see `LifterNetwork`) and how a 2D pose is turned into its input."""

    width: int = 1024
    """Hidden width of every layer."""
    stages: int = 2
    """1 = Martinez et al.'s network; 2 = the authors' encoder + decoder."""
    blocks_per_stage: int = 2
    """Residual blocks (two Linear-BatchNorm-ReLU-Dropout layers each) per stage."""
    dropout_rate: float = 0.5
    """Dropout probability after every hidden layer (0 disables it)."""
    use_batchnorm: bool = True
    """BatchNorm after every hidden Linear layer."""
    input_normalization: Literal["intrinsics", "intrinsics_scale", "intrinsics_median"] = "intrinsics_median"
    """2D input: through K^-1 and root-relative ("intrinsics"), then scaled to unit MEDIAN distance to the root
    with far joints pulled in ("intrinsics_median": one wild joint cannot shrink the others), or to unit RMS
    distance ("intrinsics_scale", the default before; same accuracy on Human3.6M: docs/robust_input.md)."""
    temporal_window: int = 1
    """Frames of one view the lifter sees per prediction (1, 3, 9, 27, 81 or 243): 1 = one frame (the paper);
    T > 1 = the T frames centred on the predicted one, through dilated temporal convolutions (see
    `LifterNetwork`).  Training, evaluation and prediction then need each recording's frames
    in order (docs/temporal.md)."""

    def __post_init__(self):
        temporal_levels(self.temporal_window)  # a clear error for a window that is not a power of 3

    def build(self, num_joints: int) -> LifterNetwork:
        """The network for a skeleton of `num_joints` joints."""
        return LifterNetwork(
            num_joints=num_joints,
            width=self.width,
            stages=self.stages,
            blocks_per_stage=self.blocks_per_stage,
            dropout_rate=self.dropout_rate,
            use_batchnorm=self.use_batchnorm,
            temporal_window=self.temporal_window,
        )


def make_eval_step(model: LifterNetwork, model_config: ModelConfig) -> Callable[..., jax.Array]:
    """Jitted single-view inference: eval_step(variables, keypoints2d [N, J, 2] undistorted px (a temporal
    lifter: windows [N, T, J, 2]), K [N, 3, 3], confidence [N, J] ([N, T, J])) -> [N, J, 3] mm, root-relative
    in the camera frame (of the window's centre frame).  Training evaluates, and serving lifts, with it."""

    @jax.jit
    def eval_step(variables, keypoints2d, K, confidence):
        inputs = normalize_views(keypoints2d, K, confidence, model_config.input_normalization)
        return model.apply(variables, inputs, train=False)

    return eval_step
