"""Train-step time of the temporal lifter against the frame lifter, in one process, as ratios.

The same jitted step (`jaxpose.training.step`) on batches of the synthetic data set (4 views), for each
temporal window T, with the batch's windows gathered on the host as training does: the median step
time and T = 1's samples/s divided by each window's.  The ratios set the epochs of a temporal run at the
frame lifter's wall-clock budget (docs/temporal.md).

    python -m benchmarks.temporal_step [--batch-size 128] [--width 512] [--lifters 1:2 9:2 9:1 1:1] [--steps 40]

Each lifter is WINDOW:STAGES (`--model.temporal-window`, `--model.stages`); the first is the reference.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections.abc import Sequence
from typing import Annotated

import jax
import numpy as np
import tyro

from jaxpose.training import pseudo_labelling
from jaxpose.training.config import RESCALED_LOSS, OptimizerConfig, PseudoLabelConfig
from jaxpose.model import ModelConfig
from jaxpose.synthetic import SyntheticConfig, generate
from jaxpose.training.step import init_train_state, jit_train_step, make_train_step


def step_seconds(dataset, window: int, stages: int, batch_size: int, width: int, steps: int) -> float:
    """Median seconds of one train step (after 3 compiling/warm-up steps), batches drawn at random."""
    config = ModelConfig(width=width, dropout_rate=0.1, temporal_window=window, stages=stages)
    model = config.build(dataset.skeleton.num_joints)
    optimizer = OptimizerConfig().build(steps + 3)
    state = init_train_state(model, optimizer, jax.random.key(0))
    step = jit_train_step(make_train_step(model, config, optimizer, RESCALED_LOSS, steps + 3))
    rng = np.random.default_rng(0)
    key = jax.random.key(1)
    times = []
    for index in range(steps + 3):
        start = time.perf_counter()
        batch = dataset.batch(rng.choice(len(dataset), batch_size, replace=False), window)  # host gather counted
        state, metrics = step(state, batch, key, index % 50 == 49)  # the shares of a run logging every 50 steps
        jax.block_until_ready(metrics)
        if index >= 3:
            times.append(time.perf_counter() - start)
    return float(np.median(times))


@dataclasses.dataclass(frozen=True)
class Args:
    """The benchmark's flags."""

    batch_size: int = 128
    """Multi-view samples per step (the dev / cpu presets: 128)."""
    width: int = 512
    """Lifter width (the presets: 512)."""
    lifters: Annotated[tuple[str, ...], tyro.conf.arg(metavar="WINDOW:STAGES [...]")] = ("1:2", "3:2", "9:2", "27:2", "9:1", "27:1", "1:1")
    """WINDOW:STAGES of each lifter to time; the first is the reference."""
    steps: int = 40
    """Timed steps per lifter (the median is reported)."""


def main(argv: Sequence[str] | None = None) -> None:
    args = tyro.cli(Args, args=argv, description=__doc__, prog="python -m benchmarks.temporal_step")
    dataset = generate(SyntheticConfig())
    dataset = pseudo_labelling.label(dataset.subset(np.arange(20000)), PseudoLabelConfig(method="normal"))
    lifters = [tuple(int(v) for v in lifter.split(":")) for lifter in args.lifters]
    seconds = {lifter: step_seconds(dataset, *lifter, args.batch_size, args.width, args.steps) for lifter in lifters}
    reference = seconds[lifters[0]]
    print(f"{os.cpu_count()} cores, batch {args.batch_size} x 4 views, width {args.width}, median of {args.steps} steps")
    print(f"| window T | stages | ms / step | samples / s | speed vs {args.lifters[0]} |")
    print("|---|---|---:|---:|---:|")
    for (window, stages), value in seconds.items():
        print(f"| {window} | {stages} | {value * 1e3:.1f} | {args.batch_size / value:.0f} | {reference / value:.2f}x |")
    print(json.dumps({"cpus": os.cpu_count(), "batch_size": args.batch_size, "width": args.width,
                      "seconds": {f"{w}:{s}": v for (w, s), v in seconds.items()}}))


if __name__ == "__main__":
    main()
