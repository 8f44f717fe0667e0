"""How far a recovered rig is from a reference calibration, up to the similarity that no
calibration from images alone can fix (world origin, orientation and, in part, scale)."""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxpose.camera import camera_centres
from jaxpose.rotations import nearest_rotation


@dataclasses.dataclass(frozen=True)
class RigComparison:
    """Errors of a recovered rig against a reference, per camera after a similarity alignment."""

    rotation_deg: np.ndarray
    """f64[C] angle between the aligned and the reference camera rotation."""
    centre_mm: np.ndarray
    """f64[C] distance between the aligned and the reference camera centre."""
    scale_error: float
    """recovered size / reference size - 1 (0.03: the recovered rig is 3% too large)."""
    aligned_centres: np.ndarray
    """f64[C, 3] the recovered centres in the reference world frame (after alignment)."""
    aligned_R: np.ndarray
    """f64[C, 3, 3] the recovered rotations in the reference world frame."""


def compare_rigs(R: np.ndarray, t: np.ndarray, R_ref: np.ndarray, t_ref: np.ndarray) -> RigComparison:
    """Align the recovered rig (R [C, 3, 3], t [C, 3]) to the reference and measure the errors.

    The alignment maps recovered world points X to s Q X + u.  Q is the rotation that best agrees
    with every camera's orientation (x_cam = R X = R_ref Q X, so Q ~ R_ref^T R per camera; their
    chordal mean), which is defined for any number of cameras, even two; s and u then fit the
    camera centres by least squares.
    """
    Q = nearest_rotation(np.einsum("cji,cjk->ik", R_ref, R))
    centres, reference = camera_centres(R, t) @ Q.T, camera_centres(R_ref, t_ref)
    centred, reference_centred = centres - centres.mean(0), reference - reference.mean(0)
    s = float(np.sum(centred * reference_centred) / np.sum(centred**2))
    aligned = s * centred + reference.mean(0)
    aligned_R = R @ Q.T
    relative = np.einsum("cij,ckj->cik", aligned_R, R_ref)
    cosine = np.clip((np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return RigComparison(
        rotation_deg=np.degrees(np.arccos(cosine)),
        centre_mm=np.linalg.norm(aligned - reference, axis=-1),
        scale_error=1.0 / s - 1.0,
        aligned_centres=aligned,
        aligned_R=aligned_R,
    )
