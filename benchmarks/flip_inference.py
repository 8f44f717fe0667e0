"""What test-time flip costs at inference: `Lifter3D.predict` with and without `flip`, as a ratio.

    python -m benchmarks.flip_inference --run runs/h36m_dev [--poses 1 64 1024 16384] [--repeats 15]

For each number of poses per call, random poses of the run's skeleton (one camera) are lifted by
`Lifter3D.predict` as users call it (checks, chunking and the host copies included), after a warm-up
call that compiles; the plain and the flipped call alternate, so that other load on the machine hits
both alike.  Prints the median milliseconds per call, poses per second and the ratio flip / plain, with
the machine's core count, and a JSON line of the same.
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import time
from collections.abc import Sequence
from typing import Annotated

import numpy as np
import tyro

from jaxpose.serving import inference


def seconds_per_call(lifter: inference.Lifter3D, count: int, repeats: int) -> dict[str, float]:
    """Median seconds of `predict` on `count` poses, plain and flipped, over `repeats` alternating calls."""
    rng = np.random.default_rng(count)
    keypoints = rng.uniform(300.0, 700.0, (count, lifter.num_joints, 2)).astype(np.float32)
    K = np.array([[1150.0, 0.0, 500.0], [0.0, 1150.0, 500.0], [0.0, 0.0, 1.0]], np.float32)
    times = {"plain": [], "flip": []}
    for index in range(repeats + 1):
        for name in times:
            start = time.perf_counter()
            lifter.predict(keypoints, K, flip=name == "flip")
            if index:  # the first call of each compiles
                times[name].append(time.perf_counter() - start)
    return {name: float(np.median(values)) for name, values in times.items()}


@dataclasses.dataclass(frozen=True)
class Args:
    """The benchmark's flags."""

    run: Annotated[pathlib.Path, tyro.conf.arg(metavar="RUN")]
    """Run directory of the lifter timed."""
    poses: tuple[int, ...] = (1, 64, 1024, 16384)
    """Poses per `predict` call: one measurement for each."""
    repeats: int = 15
    """Timed calls of each kind per size (the median is reported)."""


def main(argv: Sequence[str] | None = None) -> dict:
    args = tyro.cli(Args, args=argv, description=__doc__, prog="python -m benchmarks.flip_inference")
    lifter = inference.load(args.run)
    seconds = {count: seconds_per_call(lifter, count, args.repeats) for count in args.poses}
    cores = len(os.sched_getaffinity(0))
    config = lifter.model_config
    print(
        f"{cores} cores; lifter {args.run} (width {config.width}, {config.stages} stages x {config.blocks_per_stage}"
        f" blocks, window {config.temporal_window}, J = {lifter.num_joints}); median of {args.repeats} calls"
    )
    print("| poses per call | plain: ms / call | poses / s | flip: ms / call | poses / s | flip / plain |")
    print("|---:|---:|---:|---:|---:|---:|")
    for count, value in seconds.items():
        plain, flip = value["plain"], value["flip"]
        print(f"| {count} | {plain * 1e3:.2f} | {count / plain:.0f} | {flip * 1e3:.2f} | {count / flip:.0f} | {flip / plain:.2f} |")
    result = {"cores": cores, "run": str(args.run), "repeats": args.repeats, "seconds": {str(k): v for k, v in seconds.items()}}
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
