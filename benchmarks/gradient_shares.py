"""What measuring the terms' gradient shares costs a train step, and what measuring them on logged
steps only saves.

    python -m benchmarks.gradient_shares [--rounds 60]

The main job's step (`experiments.synthetic` defaults: width 512, batch 256, 4 views, 17 joints, all
four terms on) compiled twice: measuring the shares on every step (`share_every=1`, what every step
did before) and on every 50th (`share_every=50`, the runner's default log interval: 49 of 50 steps
skip the four backward pulls).  The two run interleaved in one process, one call each per round, so
that a change of load on a shared machine hits both; medians of wall and process CPU time.
"""

from __future__ import annotations

import dataclasses
import os
import statistics
from collections.abc import Sequence

import jax
import tyro

from benchmarks.train_step import synthetic_batch, timed_rounds
from experiments.synthetic import DEFAULT
from jaxpose.training.step import init_train_state, jit_train_step, make_train_step


@dataclasses.dataclass(frozen=True)
class Args:
    """The benchmark's flags."""

    rounds: int = 60
    """Timed calls of each step after one warm-up call (the median is reported)."""


def main(argv: Sequence[str] | None = None) -> dict[str, float]:
    args = tyro.cli(Args, args=argv, description=__doc__, prog="python -m benchmarks.gradient_shares")
    model_config, loss_config = DEFAULT.model, dataclasses.replace(DEFAULT.loss, output_triangulation_start=0.0)
    model = model_config.build(17)
    optimizer = DEFAULT.optimizer.build(10_000)
    batch = jax.device_put(synthetic_batch(DEFAULT.train.batch_size, 4))
    programs = {}
    for label, share_every in (("shares every step", 1), ("shares every 50th step", 50)):
        step = jit_train_step(make_train_step(model, model_config, optimizer, loss_config, 10_000))
        # Each program keeps its own state; the step donates it, so the call replaces it.
        holder = {"state": init_train_state(model, optimizer, jax.random.key(0)), "calls": 0}

        def run(step=step, holder=holder, share_every=share_every):
            holder["calls"] += 1
            holder["state"], metrics = step(holder["state"], batch, jax.random.key(1), holder["calls"] % share_every == 0)
            return metrics["loss"]

        jax.block_until_ready(run())
        programs[label] = run
    times = timed_rounds(programs, args.rounds)
    medians = {label: {kind: statistics.median(values) for kind, values in t.items()} for label, t in times.items()}
    every, logged = medians["shares every step"], medians["shares every 50th step"]
    print(f"{os.cpu_count()} cores, jax {jax.__version__}, {args.rounds} rounds, batch {DEFAULT.train.batch_size} x 4 views")
    print("| shares measured | step ms (wall) | step ms (CPU) |\n|---|---|---|")
    for label, median in medians.items():
        print(f"| {label} | {1000 * median['wall']:.1f} | {1000 * median['cpu']:.1f} |")
    ratio = {kind: every[kind] / logged[kind] for kind in ("wall", "cpu")}
    print(f"every step / every 50th: {ratio['wall']:.3f} (wall), {ratio['cpu']:.3f} (CPU)")
    return ratio


if __name__ == "__main__":
    main()
