"""A PyTorch equivalent of `jaxpose.training.step`'s train step, for speed comparisons on the same machine.

Written from the paper (Sec. III) and docs/method.md "Method choices", with the conventions of
`jaxpose.losses` (metres / focal-normalized units, means over valid entries, root excluded,
stop-gradient targets for L_con and L_out): the same network (2 stages x 2 residual blocks of
Linear-BatchNorm-ReLU-Dropout(0.5), width 1024, all C views as one batch of B*C poses), the four
losses with all four weights on, the output triangulation by batched DLT (row-normalized,
balanced, smallest right singular vector, as `jaxpose.triangulation`'s "svd"), and Adam.  It is
a benchmark, not a second implementation to train with: it handles undistorted pinhole cameras
only and is not tested against the JAX losses beyond agreeing on a batch
(`python -m benchmarks.torch_reference` prints both).

`make_step(arrays, compiled)` returns a callable that runs one optimizer step; with `compiled`,
the forward pass and the losses go through `torch.compile` (their backward is compiled along
with them by AOTAutograd); the optimizer step stays eager in both, as in most training loops.
"""

from __future__ import annotations

import os
from collections.abc import Callable

import numpy as np
import torch
from torch import nn

MM_PER_M = 1000.0
WEIGHTS = (1.0, 1.0, 0.001, 0.01)  # the paper's omega_1..omega_4


class DenseBlock(nn.Sequential):
    def __init__(self, fan_in: int, width: int, dropout: float):
        linear = nn.Linear(fan_in, width, bias=False)  # BatchNorm's shift makes a bias redundant
        nn.init.kaiming_normal_(linear.weight, nonlinearity="relu")
        super().__init__(linear, nn.BatchNorm1d(width, eps=1e-5, momentum=0.1), nn.ReLU(), nn.Dropout(dropout))


class ResidualBlock(nn.Module):
    def __init__(self, width: int, dropout: float):
        super().__init__()
        self.layers = nn.Sequential(DenseBlock(width, width, dropout), DenseBlock(width, width, dropout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.layers(x)


class LifterNetwork(nn.Module):
    """[N, J, 2] normalized 2D -> [N, J, 3] root-relative mm (root row zero), as `jaxpose.model.LifterNetwork`."""

    def __init__(self, num_joints: int, width: int = 1024, stages: int = 2, blocks_per_stage: int = 2, dropout: float = 0.5):
        super().__init__()
        layers, fan_in = [], 2 * num_joints
        for _ in range(stages):
            layers.append(DenseBlock(fan_in, width, dropout))
            layers += [ResidualBlock(width, dropout) for _ in range(blocks_per_stage)]
            fan_in = width
        out = nn.Linear(width, 3 * num_joints)
        nn.init.normal_(out.weight, std=(1e-3 / width) ** 0.5)
        nn.init.zeros_(out.bias)
        self.net = nn.Sequential(*layers, out)
        self.num_joints = num_joints
        self.register_buffer("not_root", torch.ones(num_joints, 1).index_fill_(0, torch.tensor([0]), 0.0))

    def forward(self, keypoints: torch.Tensor) -> torch.Tensor:
        pose = self.net(keypoints.flatten(1)).view(-1, self.num_joints, 3) * MM_PER_M
        return pose * self.not_root


def normalize_keypoints(pixels: torch.Tensor, K: torch.Tensor, confidence: torch.Tensor) -> torch.Tensor:
    """Through K^-1, root-relative, scaled to unit RMS ("intrinsics_scale"); missing joints zero."""
    fx, fy, skew = K[..., 0, 0, None], K[..., 1, 1, None], K[..., 0, 1, None]
    cx, cy = K[..., 0, 2, None], K[..., 1, 2, None]
    y = (pixels[..., 1] - cy) / fy
    x = (pixels[..., 0] - cx - skew * y) / fx
    normalized = torch.stack([x, y], -1)
    valid = ((confidence > 0) & (confidence[..., :1] > 0)).to(pixels.dtype)
    relative = (normalized - normalized[..., :1, :]) * valid[..., None]
    count = torch.clamp(valid.sum(-1, keepdim=True) - 1.0, min=1.0)
    mean_square = (relative**2).sum((-2, -1))[..., None] / count
    return relative / torch.sqrt(mean_square + 1e-12)[..., None]


def to_camera(R: torch.Tensor, t: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """World [..., N, 3] -> camera frame, with R [..., 3, 3] and t [..., 3] broadcasting."""
    return points @ R.transpose(-1, -2) + t[..., None, :]


def to_world(R: torch.Tensor, t: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    return (points - t[..., None, :]) @ R


def project(K: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Camera frame [..., N, 3] -> pixels [..., N, 2]; depth clamped at 1 mm like jaxpose.camera."""
    xy = points[..., :2] / torch.clamp(points[..., 2:3], min=1.0)
    return xy @ K[..., :2, :2].transpose(-1, -2) + K[..., None, :2, 2]


def triangulate(P: torch.Tensor, points2d: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Batched DLT: P [B, C, 3, 4], points [B, C, J, 2], weights [B, C, J] -> world [B, J, 3]."""
    rows = torch.stack(
        [points2d[..., 0:1] * P[:, :, None, 2] - P[:, :, None, 0], points2d[..., 1:2] * P[:, :, None, 2] - P[:, :, None, 1]],
        dim=-2,
    )  # [B, C, J, 2, 4]
    rows = rows / torch.clamp(torch.linalg.vector_norm(rows[..., :3], dim=-1, keepdim=True), min=1e-12)
    rows = torch.where(weights[..., None, None] > 0, rows * weights[..., None, None], 0.0)
    A = rows.permute(0, 2, 1, 3, 4).reshape(rows.shape[0], rows.shape[2], -1, 4)  # [B, J, 2C, 4]
    scale = torch.sqrt(torch.mean(A[..., 3] ** 2, dim=-1, keepdim=True)) + 1.0
    balanced = A * torch.cat([scale.expand(*scale.shape[:-1], 3), torch.ones_like(scale)], -1)[..., None, :]
    solution = torch.linalg.svd(balanced, full_matrices=False).Vh[..., -1, :]
    w = solution[..., 3:4]
    w = torch.where(w.abs() < 1e-12, torch.where(w < 0, -1e-12, 1e-12), w)
    return solution[..., :3] / w * scale


def _masked_mean(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    mask = mask.expand_as(values)
    return torch.sum(torch.where(mask > 0, values * mask, 0.0)) / torch.clamp(mask.sum(), min=1.0)


def total_loss(pred: torch.Tensor, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """pred [B, C, J, 3] -> omega-weighted sum of L_in, L_proj, L_con, L_out and the four terms."""
    K, R, t = batch["K"], batch["R"], batch["t"]
    keypoints, confidence, pseudo3d = batch["keypoints2d"], batch["confidence"], batch["pseudo3d"]
    num_views, num_joints = pred.shape[1], pred.shape[2]
    not_root = torch.ones(num_joints, dtype=pred.dtype).index_fill_(0, torch.tensor([0]), 0.0)
    views = (confidence[..., 0] > 0).to(pred.dtype)  # [B, C]

    def in_views(world: torch.Tensor) -> torch.Tensor:  # world [B, J, 3] -> root-relative per view
        cam = to_camera(R, t, world[:, None])
        return cam - cam[..., :1, :]

    def l2_to(target: torch.Tensor) -> torch.Tensor:
        squared = torch.sum(((target - pred) / MM_PER_M) ** 2, -1)  # [B, C, J]
        return _masked_mean(squared, views[..., None] * not_root)

    root_camera = to_camera(R, t, pseudo3d[:, None, :1])  # [B, C, 1, 3]
    absolute = pred + root_camera
    # L_proj: every view's prediction projected into every view c: [B, C (target), C' (source), J, 2].
    world = to_world(R, t, absolute)
    projected = project(K[:, :, None], to_camera(R[:, :, None], t[:, :, None], world[:, None]))
    projected = projected - projected[..., :1, :]
    detected = keypoints - keypoints[..., :1, :]
    focal = torch.stack([K[..., 0, 0], K[..., 1, 1]], -1)[:, :, None, None]
    error = torch.sum(torch.abs(projected - detected[:, :, None]) / focal, -1)
    valid = ((confidence > 0) & (confidence[..., :1] > 0)).to(pred.dtype)
    reprojection = _masked_mean(error, valid[:, :, None] * views[:, None, :, None] * not_root)
    # L_con: view c' rotated into camera c against view c (the target).
    relative = R[:, :, None] @ R[:, None].transpose(-1, -2)  # [B, C, C', 3, 3]
    rotated = pred[:, None] @ relative.transpose(-1, -2)
    error = torch.sum(torch.abs(rotated - pred.detach()[:, :, None]), -1) / MM_PER_M
    pairs = views[:, :, None] * views[:, None, :] * (1.0 - torch.eye(num_views, dtype=pred.dtype))
    consistency = _masked_mean(error, pairs[..., None] * not_root)
    # L_out: each view's prediction projected into its own image, triangulated, a constant target.
    with torch.no_grad():
        P = K @ torch.cat([R, t[..., None]], -1)
        own = project(K, absolute)
        output3d = triangulate(P, own, views[..., None].expand(own.shape[:-1]))
    terms = {
        "input_triangulation": l2_to(in_views(pseudo3d)),
        "reprojection": reprojection,
        "consistency": consistency,
        "output_triangulation": l2_to(in_views(output3d)),
    }
    return sum(w * term for w, term in zip(WEIGHTS, terms.values())), terms


def tensors(arrays: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
    return {name: torch.from_numpy(np.array(value, np.float32)) for name, value in arrays.items()}


def make_step(arrays: dict[str, np.ndarray], compiled: bool, seed: int = 0) -> Callable[[], float]:
    """One training step per call (returns the loss) on a fixed batch.

    `arrays`: keypoints2d [B, C, J, 2] px, confidence [B, C, J], K/R [B, C, 3, 3], t [B, C, 3],
    pseudo3d [B, J, 3] world mm.
    """
    torch.set_num_threads(os.cpu_count() or 1)
    torch.manual_seed(seed)
    batch = tensors(arrays)
    B, C, J, _ = batch["keypoints2d"].shape
    model = LifterNetwork(J).train()
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)

    def loss_fn() -> torch.Tensor:
        inputs = normalize_keypoints(batch["keypoints2d"], batch["K"], batch["confidence"])
        pred = model(inputs.reshape(B * C, J, 2)).view(B, C, J, 3)
        return total_loss(pred, batch)[0]

    forward = torch.compile(loss_fn) if compiled else loss_fn

    def step() -> float:
        optimizer.zero_grad(set_to_none=True)
        loss = forward()
        loss.backward()
        optimizer.step()
        return float(loss.detach())

    return step


def _compare_with_jax() -> None:
    """The four terms of both implementations on one batch with noisy predictions."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    import jax.numpy as jnp
    from geometry_helpers import exact_batch

    from jaxpose.losses import total_loss as jax_total_loss

    rng = np.random.default_rng(0)
    batch, truth = exact_batch(rng, 16, 4, 17)
    noise = rng.normal(0, 30, truth.shape).astype(np.float32)
    noise[..., 0, :] = 0
    pred = np.asarray(truth) + noise
    _, jax_terms = jax_total_loss(jnp.asarray(pred), batch)
    arrays = {
        "keypoints2d": batch.keypoints2d, "confidence": batch.confidence, "K": batch.cameras.K,
        "R": batch.cameras.R, "t": batch.cameras.t, "pseudo3d": batch.pseudo3d,
    }
    _, torch_terms = total_loss(torch.from_numpy(pred), tensors({k: np.asarray(v) for k, v in arrays.items()}))
    for name, value in jax_terms.items():
        print(f"{name:22s} jax {float(value):.6g}  torch {float(torch_terms[name]):.6g}")


if __name__ == "__main__":
    _compare_with_jax()
