"""Test-time flip augmentation: a pose and its mirror image lifted, the mirror's lift mirrored back,
the two averaged (as published lifters do at evaluation).

The mirror is taken in normalised camera coordinates, x -> -x of K^-1 [u, v, 1] (about the principal
point, never about the image's width, which a lifter does not know), with every left/right pair of the
skeleton swapped so that the mirrored person's left arm is where the right one was seen.  A camera
whose intrinsics are K diag(-1, 1, 1) (`mirror_intrinsics`: fx and the first column negated) sees the
same pixels exactly as that mirror image, so the flip happens before the input normalisation and holds
for any of them (root-relative, the RMS or median scale: distances are unchanged by a mirror) and for
each frame of a temporal window alike.  The 3D counterpart is x -> -x in the camera frame with the
pairs swapped back (`mirror_pose3d`).  Mirroring twice is the identity, so the flip-averaged lifter
is exactly mirror-equivariant: a mirror-symmetric input gives a mirror-symmetric pose.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import numpy as np

from jaxpose.skeleton import ROOT, Skeleton

_NEGATE_X = np.array([-1.0, 1.0, 1.0], np.float32)


def mirror_intrinsics(K: jax.Array) -> jax.Array:
    """K [..., 3, 3] -> K diag(-1, 1, 1): pixels it normalises come out mirrored, (x, y) -> (-x, y)."""
    return K * _NEGATE_X


def mirror_pose3d(poses: jax.Array, skeleton: Skeleton) -> jax.Array:
    """Camera-frame poses [..., J, 3] -> their mirror images (x -> -x), left and right swapped."""
    return poses[..., skeleton.flip_permutation(), :] * _NEGATE_X


def mirror_input(keypoints: jax.Array, K: jax.Array, confidence: jax.Array, skeleton: Skeleton):
    """A lifter's input (keypoints [N, (T,) J, 2] px, K [N, 3, 3], confidence [N, (T,) J]) -> that of its
    mirror image: the same pixels, left and right swapped, seen by the mirrored camera."""
    permutation = skeleton.flip_permutation()
    return keypoints[..., permutation, :], mirror_intrinsics(K), confidence[..., permutation]


def flip_averaged(lift: Callable[..., jax.Array], skeleton: Skeleton) -> Callable[..., jax.Array]:
    """The flip-averaged counterpart of an eval step: lift(variables, keypoints, K, confidence) -> poses
    [N, J, 3] mm (`jaxpose.model.make_eval_step`'s signature), returning (lift(x) + mirror(lift(mirror(x)))) / 2.
    Two lifts per pose; jitted, so it traces into an exported graph like the plain step."""
    if skeleton.flip_permutation()[ROOT] != ROOT:
        raise ValueError(f"skeleton {skeleton.name}: the root cannot be one of a left/right pair")

    @jax.jit
    def flipped(variables, keypoints, K, confidence):
        plain = lift(variables, keypoints, K, confidence)
        mirrored = lift(variables, *mirror_input(keypoints, K, confidence, skeleton))
        return 0.5 * (plain + mirror_pose3d(mirrored, skeleton))

    return flipped

