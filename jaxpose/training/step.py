"""The train state, the pure `train_step` and its one jit (`jit_train_step`).

`train_step(state, batch, key, measure_shares)` runs the lifter on all C views of every sample as one batch
of B*C poses (so BatchNorm sees all views), evaluates the losses (the four of the paper, or the supervised
one), and applies the Adam update and the BatchNorm statistics update; jitted with the state donated.
Dropout keys are `fold_in(key, step)`, so a resumed run draws exactly the masks an uninterrupted one would.
Two switches are traced values, so neither recompiles: the output-triangulation weight (a function of the
step: on in the last 10% of training) and `measure_shares`, whether the step also measures each term's
share of the gradient (the caller sets it on the steps it logs).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import optax
from flax import struct
from jax.sharding import Mesh

from jaxpose.training import parallel
from jaxpose.camera import masked_median
from jaxpose.training.config import InputAugmentation, LossConfig
from jaxpose.model import ModelConfig
from jaxpose.data.batch import MultiViewBatch
from jaxpose.flip import mirror_input, mirror_pose3d
from jaxpose.losses import TERMS, gradient_shares, input_triangulation_loss, total_loss
from jaxpose.model import LifterNetwork, normalize_views
from jaxpose.skeleton import Skeleton


# Metric-name prefix of each term's share of the gradient w.r.t. the lifter output (`gradient_shares`).
GRADIENT_SHARE_PREFIX = "grad_share_"


@struct.dataclass
class TrainState:
    step: jax.Array
    params: Any
    batch_stats: Any
    opt_state: Any

    @property
    def variables(self) -> dict[str, Any]:
        return {"params": self.params, "batch_stats": self.batch_stats}


def init_train_state(model: LifterNetwork, optimizer: optax.GradientTransformation, key: jax.Array) -> TrainState:
    dummy = jnp.zeros(model.input_shape(2), jnp.float32)
    variables = model.init({"params": key}, dummy, train=False)
    params = variables["params"]
    return TrainState(
        step=jnp.zeros((), jnp.int32),
        params=params,
        batch_stats=variables.get("batch_stats", {}),
        opt_state=optimizer.init(params),
    )


def lifter_input_2d(batch: MultiViewBatch) -> tuple[jax.Array, jax.Array]:
    """What the lifter sees of every view: its window (keypoints [B, C, T, J, 2], confidence [B, C, T, J])
    where the batch has one, else the instant's 2D ([B, C, J, 2], [B, C, J])."""
    if batch.window2d is None:
        return batch.keypoints2d, batch.confidence
    return batch.window2d, batch.window_confidence


def augment_inputs(
    key: jax.Array,
    keypoints2d: jax.Array,
    confidence: jax.Array,
    augmentation: InputAugmentation,
    left_right_pairs: tuple[tuple[int, int], ...] = (),
) -> tuple[jax.Array, jax.Array]:
    """One detector failure per view-pose, with `augmentation`'s probabilities: keypoints2d [..., J, 2]
    and confidence [..., J] -> the same, with one joint dropped (confidence 0), displaced, or one
    left/right pair swapped.  A pure function of `key`.  The root (joint 0) is never touched."""
    shape = confidence.shape[:-1]
    J = confidence.shape[-1]
    k_kind, k_joint, k_pair, k_angle, k_length = jax.random.split(key, 5)
    u = jax.random.uniform(k_kind, shape)
    drop = u < augmentation.drop
    displace = (u >= augmentation.drop) & (u < augmentation.drop + augmentation.displace)
    swap = (u >= augmentation.drop + augmentation.displace) & (u < augmentation.drop + augmentation.displace + augmentation.swap)
    joint = jax.random.randint(k_joint, shape, 1, J)
    chosen = jnp.arange(J) == joint[..., None]  # [..., J]
    confidence = jnp.where(drop[..., None] & chosen, 0.0, confidence)
    # Displacement: a random direction, up to displace_scale x the pose's median distance to the root.
    relative = keypoints2d - keypoints2d[..., :1, :]
    distance = jnp.sqrt((relative**2).sum(-1) + 1e-12)
    others = (confidence > 0) & (jnp.arange(J) > 0)
    size = masked_median(distance, others)
    angle = jax.random.uniform(k_angle, shape, maxval=2 * jnp.pi)
    length = jax.random.uniform(k_length, shape) * augmentation.displace_scale * size
    offset = jnp.stack([jnp.cos(angle), jnp.sin(angle)], -1) * length[..., None]
    keypoints2d = keypoints2d + jnp.where((displace[..., None] & chosen)[..., None], offset[..., None, :], 0.0)
    if left_right_pairs and augmentation.swap > 0:
        pairs = jnp.asarray(left_right_pairs, jnp.int32)  # [P, 2]
        pair = pairs[jax.random.randint(k_pair, shape, 0, len(left_right_pairs))]  # [..., 2]
        source = jnp.broadcast_to(jnp.arange(J), confidence.shape)
        source = jnp.where(source == pair[..., :1], pair[..., 1:], jnp.where(source == pair[..., 1:], pair[..., :1], source))
        source = jnp.where(swap[..., None], source, jnp.arange(J))
        keypoints2d = jnp.take_along_axis(keypoints2d, source[..., None], axis=-2)
        confidence = jnp.take_along_axis(confidence, source, axis=-1)
    return keypoints2d, confidence


def mirror_views(
    key: jax.Array, keypoints2d: jax.Array, K: jax.Array, confidence: jax.Array, probability: float, skeleton: Skeleton
) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """Each view (K [..., 3, 3]; keypoints2d [..., (T,) J, 2], confidence [..., (T,) J]) replaced by its
    mirror image (`jaxpose.flip.mirror_input`) with `probability` -> (keypoints2d, K, confidence, mirrored
    [...] bool): the lift of a mirrored view is mirrored back with `jaxpose.flip.mirror_pose3d`.  A pure
    function of `key`."""
    mirrored = jax.random.bernoulli(key, probability, K.shape[:-2])

    def pick(mirror_image: jax.Array, given: jax.Array) -> jax.Array:
        return jnp.where(mirrored.reshape(mirrored.shape + (1,) * (given.ndim - mirrored.ndim)), mirror_image, given)

    mirror_image = mirror_input(keypoints2d, K, confidence, skeleton)
    keypoints2d, K, confidence = (pick(image, given) for image, given in zip(mirror_image, (keypoints2d, K, confidence)))
    return keypoints2d, K, confidence, mirrored


def output_triangulation_start_step(loss: LossConfig, total_steps: int) -> int:
    return int(round(loss.output_triangulation_start * total_steps))


def make_loss_fn(
    model: LifterNetwork, model_config: ModelConfig, loss: LossConfig, output_start_step: int,
    *,
    augmentation: InputAugmentation = InputAugmentation(),
    skeleton: Skeleton | None = None,
) -> Callable[..., tuple[jax.Array, tuple[dict[str, jax.Array], Any]]]:
    """loss_fn(params, batch_stats, batch, dropout_key, step, measure_shares) -> (loss, (metrics, new batch_stats)).

    The terms' gradient shares are computed where the traced bool `measure_shares` holds and are 0
    elsewhere: their backward pulls make the main job's step 1.13x slower (benchmarks/README.md), and
    only logged steps need them.
    """
    if skeleton is None and (augmentation.swap > 0 or augmentation.mirror > 0):
        raise ValueError("input augmentation swap / mirror: the train step needs the skeleton (its left/right pairs)")

    def loss_fn(params, batch_stats, batch: MultiViewBatch, dropout_key, step, measure_shares):
        keypoints, confidence = lifter_input_2d(batch)
        K = batch.cameras.K
        # Each augmentation has its own key, derived from the step's dropout key: the dropout masks are those
        # of a run without it.
        if augmentation.imposes_failures:
            keypoints, confidence = augment_inputs(
                jax.random.fold_in(dropout_key, 0x61756700), keypoints, confidence, augmentation,
                skeleton.left_right_pairs if skeleton is not None else (),
            )  # fmt: skip
        if augmentation.mirror > 0:
            keypoints, K, confidence, mirrored = mirror_views(
                jax.random.fold_in(dropout_key, 0x6D697272), keypoints, K, confidence, augmentation.mirror, skeleton
            )
        inputs = normalize_views(keypoints, K, confidence, model_config.input_normalization)
        pred, updates = model.apply(
            {"params": params, "batch_stats": batch_stats},
            inputs,
            train=True,
            rngs={"dropout": dropout_key},
            mutable=["batch_stats"],
        )
        if augmentation.mirror > 0:  # every loss sees the views as given
            pred = jnp.where(mirrored[..., None, None], mirror_pose3d(pred, skeleton), pred)
        if loss.supervision == "full":
            supervised = batch.replace(pseudo3d=batch.target3d, pseudo3d_weight=None)
            value = input_triangulation_loss(pred, supervised)
            metrics = {"supervised": value}
        else:
            weights = loss.weights(output_triangulation_on=step >= output_start_step)
            value, metrics = total_loss(pred, batch, weights, loss.triangulation, loss.label_robust_scale_mm)
            shares = jax.lax.cond(
                measure_shares,
                lambda p: gradient_shares(p, batch, weights, loss.triangulation, loss.label_robust_scale_mm),
                lambda p: {name: jnp.zeros((), p.dtype) for name in TERMS},
                jax.lax.stop_gradient(pred),
            )
            metrics = dict(metrics, output_triangulation_weight=weights.output_triangulation)
            metrics.update({f"{GRADIENT_SHARE_PREFIX}{name}": share for name, share in shares.items()})
        return value, (metrics, updates.get("batch_stats", batch_stats))

    return loss_fn


def make_train_step(
    model: LifterNetwork,
    model_config: ModelConfig,
    optimizer: optax.GradientTransformation,
    loss: LossConfig,
    total_steps: int,
    *,
    augmentation: InputAugmentation = InputAugmentation(),
    skeleton: Skeleton | None = None,
) -> Callable[..., tuple[TrainState, dict[str, jax.Array]]]:
    """The pure train step `train_step(state, batch, key, measure_shares=False) -> (state, metrics)`
    (un-jitted; see `jit_train_step`).

    The metrics' gradient shares are measured where `measure_shares` (a bool, traced: one program for
    both) is true and are 0 elsewhere; the parameters do not depend on it.  `augmentation` perturbs the
    lifter's input only (`augment_inputs`, `mirror_views`: a mirrored view's lift is mirrored back before
    the losses); its swaps and mirror need the `skeleton`'s left/right pairs.
    """
    if loss.supervision not in ("self", "full"):
        raise ValueError(f"unknown supervision {loss.supervision!r}; expected 'self' or 'full'")
    loss_fn = make_loss_fn(
        model, model_config, loss, output_triangulation_start_step(loss, total_steps),
        augmentation=augmentation, skeleton=skeleton,
    )  # fmt: skip
    grad_fn = jax.value_and_grad(loss_fn, has_aux=True)

    def train_step(state: TrainState, batch: MultiViewBatch, key: jax.Array, measure_shares: jax.Array | bool = False):
        if loss.supervision == "full" and batch.target3d is None:
            raise ValueError(
                "supervision='full' needs batch.target3d (a training set recalibrated with another calibration"
                " has none: its world frame is not the motion capture's)"
            )
        dropout_key = jax.random.fold_in(key, state.step)
        (value, (metrics, batch_stats)), grads = grad_fn(
            state.params, state.batch_stats, batch, dropout_key, state.step, jnp.asarray(measure_shares, bool)
        )
        updates, opt_state = optimizer.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        metrics = dict(metrics, loss=value, grad_norm=optax.tree.norm(grads))
        new_state = TrainState(step=state.step + 1, params=params, batch_stats=batch_stats, opt_state=opt_state)
        return new_state, metrics

    return train_step


def jit_train_step(train_step: Callable, mesh: Mesh | None = None) -> Callable:
    """The jit of `train_step(state, batch, key, measure_shares) -> (state, metrics)` over the devices of
    `mesh` (None: the default device alone), the one way a train step is compiled.

    State, key and switch replicated, batch split by samples, outputs replicated (`jaxpose.training.parallel`);
    the state is donated, so its buffers are reused for the new state.
    """
    mesh = parallel.data_mesh(1) if mesh is None else mesh
    copy, split = parallel.replicated(mesh), parallel.batch_sharding(mesh)
    return jax.jit(train_step, in_shardings=(copy, split, copy, copy), out_shardings=(copy, copy), donate_argnums=0)
