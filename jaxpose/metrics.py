"""3D pose metrics on `[N, J, 3]` poses (mm), batched in JAX.

Every metric averages over all J joints including the root, as VideoPose3D and the paper do, and
returns per-sample values `[N]` (take the mean for the table entry) except `pck`/`auc`, which
return per-sample fractions as well.  Poses are compared as given: make both root-relative first
(the lifter output already is).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

PCK_THRESHOLD_MM = 150.0
AUC_THRESHOLDS_MM = tuple(float(t) for t in range(0, 155, 5))  # 0, 5, ..., 150


def joint_errors(pred: jax.Array, target: jax.Array) -> jax.Array:
    """Per-joint Euclidean distances [N, J]."""
    return jnp.linalg.norm(pred - target, axis=-1)


def mpjpe(pred: jax.Array, target: jax.Array) -> jax.Array:
    """Mean per-joint position error [N]."""
    return joint_errors(pred, target).mean(-1)


def procrustes_align(pred: jax.Array, target: jax.Array) -> jax.Array:
    """`pred` after the similarity transform (rotation, translation, scale) that best fits `target`.

    Umeyama's closed form: with centred X (pred) and Y (target), H = X^T Y = U S V^T, the rotation
    is R = U D V^T (D flips the last axis when det(U V^T) < 0, excluding reflections) acting as X R,
    and the scale is trace(D S) / ||X||^2.
    """
    mu_pred = pred.mean(-2, keepdims=True)
    mu_target = target.mean(-2, keepdims=True)
    x = pred - mu_pred
    y = target - mu_target
    u, s, vt = jnp.linalg.svd(jnp.einsum("...ji,...jk->...ik", x, y))
    sign = jnp.sign(jnp.linalg.det(jnp.einsum("...ij,...jk->...ik", u, vt)))
    sign = jnp.where(sign == 0, 1.0, sign)
    d = jnp.concatenate([jnp.ones_like(s[..., :2]), sign[..., None]], axis=-1)
    rotation = jnp.einsum("...ij,...j,...jk->...ik", u, d, vt)
    scale = jnp.sum(s * d, axis=-1) / jnp.maximum(jnp.sum(x**2, axis=(-2, -1)), 1e-12)
    return scale[..., None, None] * jnp.einsum("...ij,...jk->...ik", x, rotation) + mu_target


def p_mpjpe(pred: jax.Array, target: jax.Array) -> jax.Array:
    """MPJPE after Procrustes alignment (rotation, translation, scale) [N] (protocol 2)."""
    return mpjpe(procrustes_align(pred, target), target)


def n_mpjpe(pred: jax.Array, target: jax.Array) -> jax.Array:
    """MPJPE after the least-squares scale alone, s = <pred, target> / <pred, pred>  [N]."""
    scale = jnp.sum(pred * target, axis=(-2, -1)) / jnp.maximum(jnp.sum(pred * pred, axis=(-2, -1)), 1e-12)
    return mpjpe(scale[..., None, None] * pred, target)


def pck(pred: jax.Array, target: jax.Array, threshold: float = PCK_THRESHOLD_MM) -> jax.Array:
    """Fraction of joints within `threshold` mm [N] (3DPCK of MPI-INF-3DHP at 150 mm)."""
    return (joint_errors(pred, target) <= threshold).mean(-1)


def auc(pred: jax.Array, target: jax.Array, thresholds: tuple[float, ...] = AUC_THRESHOLDS_MM) -> jax.Array:
    """PCK averaged over thresholds 0..150 mm in 5 mm steps [N]."""
    errors = joint_errors(pred, target)[..., None]
    return (errors <= jnp.asarray(thresholds)).mean((-2, -1))


def aligned_joint_errors(pred: jax.Array, target: jax.Array) -> jax.Array:
    """Per-joint distances [N, J] after the Procrustes alignment of the whole pose (their mean over
    the joints is `p_mpjpe`)."""
    return joint_errors(procrustes_align(pred, target), target)


ALL_METRICS = {"mpjpe": mpjpe, "p_mpjpe": p_mpjpe, "n_mpjpe": n_mpjpe, "pck": pck, "auc": auc}
# Per-joint forms [N, J] of two metrics, for the per-joint tables of the reports.
JOINT_METRICS = {"mpjpe": joint_errors, "p_mpjpe": aligned_joint_errors}


@jax.jit
def pose_metrics(pred: jax.Array, target: jax.Array) -> dict[str, jax.Array]:
    """All metrics at once, per sample: {"mpjpe": [N], "p_mpjpe": [N], ...}."""
    return {name: metric(pred, target) for name, metric in ALL_METRICS.items()}


@jax.jit
def per_joint_metrics(pred: jax.Array, target: jax.Array) -> dict[str, jax.Array]:
    """`JOINT_METRICS` per sample and joint: {"mpjpe": [N, J], "p_mpjpe": [N, J]}."""
    return {name: metric(pred, target) for name, metric in JOINT_METRICS.items()}
