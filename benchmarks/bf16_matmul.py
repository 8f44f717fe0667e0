"""Would bf16 matrix products (f32 accumulation) speed up the train step on this CPU?

    python -m benchmarks.bf16_matmul

Times the step's largest product, 32768 x 1024 @ 1024 x 1024 (batch 8192 x 4 views through one
hidden layer of the paper's width), in float32 and in bfloat16 with float32 accumulation, with
the operands cast inside the program (what a mixed-precision step would do) and already in
bfloat16 (its best case).  Interleaved, medians of `--rounds`.  The CPU's bf16 instruction sets
are printed with the result: without AVX512-BF16 or AMX, XLA emulates the bf16 product and it
is no faster than float32, so jaxpose offers no bf16 switch.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import tyro

from benchmarks.train_step import medians, timed_rounds

ROWS, FAN_IN, FAN_OUT = 8192 * 4, 1024, 1024


def bf16_instruction_sets() -> list[str]:
    flags = next((line for line in Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("flags")), "")
    return sorted(flag for flag in flags.split() if "bf16" in flag or flag.startswith("amx"))


@dataclasses.dataclass(frozen=True)
class Args:
    """The benchmark's flags."""

    rounds: int = 5
    """Timed calls of each program after warm-up (the median is reported)."""


def main(argv: Sequence[str] | None = None) -> None:
    args = tyro.cli(Args, args=argv, description=__doc__, prog="python -m benchmarks.bf16_matmul")
    rng = np.random.default_rng(0)
    x = jnp.asarray(rng.standard_normal((ROWS, FAN_IN)), jnp.float32)
    w = jnp.asarray(rng.standard_normal((FAN_IN, FAN_OUT)), jnp.float32)
    x16, w16 = x.astype(jnp.bfloat16), w.astype(jnp.bfloat16)
    float32 = jax.jit(lambda a, b: a @ b)
    mixed = jax.jit(lambda a, b: jnp.matmul(a, b, preferred_element_type=jnp.float32))
    cast_inside = jax.jit(lambda a, b: mixed(a.astype(jnp.bfloat16), b.astype(jnp.bfloat16)))
    programs = {
        "float32": lambda: float32(x, w),
        "bf16, cast inside": lambda: cast_inside(x, w),
        "bf16 operands": lambda: mixed(x16, w16),
    }
    for run in programs.values():
        jax.block_until_ready(run())
    median = {name: times["wall"] for name, times in medians(timed_rounds(programs, args.rounds)).items()}
    print(f"{ROWS} x {FAN_IN} @ {FAN_IN} x {FAN_OUT}, {os.cpu_count()} cores, bf16 instructions: {bf16_instruction_sets() or 'none'}")
    for name, seconds in median.items():
        print(f"{name:18s} {seconds * 1e3:7.0f} ms   float32 time / this = {median['float32'] / seconds:.2f}")


if __name__ == "__main__":
    main()
