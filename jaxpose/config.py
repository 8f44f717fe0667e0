"""The library's configuration dataclasses: model, losses, optimizer.

They live in the library, not in `experiments/`, because a checkpoint must be loadable (the model
rebuilt from its saved config) by code that knows nothing of the experiments.  The experiments'
config tree (`experiments.config`) composes them with data, run and parallelism settings.
"""

from __future__ import annotations

import dataclasses
from typing import Annotated, Literal

import jax
import jax.numpy as jnp
import tyro

from jaxpose.losses import LossWeights


@dataclasses.dataclass(frozen=True)
class ModelConfig:
    """The lifter (see `jaxpose.model.Lifter`) and how a 2D pose is turned into its input."""

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
    input_normalization: Literal["intrinsics", "intrinsics_scale"] = "intrinsics_scale"
    """2D input: through K^-1 and root-relative ("intrinsics"), then scaled to unit RMS ("intrinsics_scale")."""


@dataclasses.dataclass(frozen=True)
class LossConfig:
    """Loss weights (defaults: the paper's values; see `RESCALED_LOSS` for weights suited to this
    library's units), the output-triangulation schedule, and the supervision mode."""

    input_triangulation: float = 1.0
    """omega_1: pseudo-label (input triangulation) term, metres^2."""
    reprojection: float = 1.0
    """omega_2: re-projection term, focal-normalized image units."""
    consistency: float = 0.001
    """omega_3: cross-view consistency term, metres."""
    output_triangulation: float = 0.01
    """omega_4: output triangulation term, metres^2."""
    output_triangulation_start: float = 0.9
    """Fraction of training after which the output triangulation term is switched on (paper: last 10%)."""
    label_robust_scale_mm: float = 0.0
    """0: L_in and L_out are squared distances (the paper's L2).  > 0: a pseudo-Huber of this scale
    (mm): squared below it, linear above, so that gross pseudo-label errors pull no harder than
    moderate ones."""
    triangulation: Literal["svd", "eigh", "normal"] = "normal"
    """Solver of the output triangulation inside the train step (see jaxpose.triangulation): the
    closed-form "normal" is as accurate as the reference "svd" and ~10x faster on CPU."""
    supervision: Annotated[Literal["self", "full"], tyro.conf.arg(aliases=("--supervision",))] = "self"
    """"self": the four geometric losses; "full": L2 to the 3D ground truth (the supervised upper bound)."""

    def weights(self, output_triangulation_on: bool | jax.Array = True) -> LossWeights:
        """omega_1..omega_4 as the losses take them; omega_4 is 0 until `output_triangulation_on`
        (a traced bool inside the train step, so switching L_out on does not recompile it)."""
        return LossWeights(
            input_triangulation=self.input_triangulation,
            reprojection=self.reprojection,
            consistency=self.consistency,
            output_triangulation=jnp.where(output_triangulation_on, self.output_triangulation, 0.0),
        )


# The paper's weights rescaled to this library's units.  The terms are means over views and joints
# with 3D in metres and 2D in focal-normalised image units, and at unit weight their gradients with
# respect to the lifter output are within an order of magnitude of each other.  The paper's
# omega_3 = 0.001 and omega_4 = 0.01 were set for its own units: with ours, on the real Human3.6M
# development split, L_con and L_out end training with 0.2% and 0.3% of that gradient, i.e. they
# do nothing.  Ten times larger, they carry 2-3% each.  A hundred times larger (shares of
# 10-22%) cost 0.5-1.6 mm P-MPJPE there in three comparisons: both terms pull each view's
# prediction towards the views' consensus, which on real detections holds the same detector biases
# as the pseudo-labels, and away from L_in and L_proj.  L_out starts at half of training rather than
# in the last 10%: under a cosine schedule the learning rate in the last 10% is below 3% of its
# peak, too little for a new term to move the model; at the half it is still at 50%.
RESCALED_LOSS = LossConfig(consistency=0.01, output_triangulation=0.1, output_triangulation_start=0.5)


@dataclasses.dataclass(frozen=True)
class OptimizerConfig:
    """Adam with an optional learning-rate schedule."""

    learning_rate: float = 1e-3
    """Peak learning rate (paper: 1e-3)."""
    schedule: Literal["constant", "cosine"] = "constant"
    """"constant" (paper) or "cosine" decay to `final_learning_fraction` of the peak."""
    warmup_steps: int = 0
    """Linear warm-up steps before the schedule."""
    final_learning_fraction: float = 0.01
    """With "cosine": the final learning rate as a fraction of the peak."""
    gradient_clip_norm: float = 0.0
    """Clip the global gradient norm to this value (0 = no clipping)."""
