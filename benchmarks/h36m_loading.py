"""Time and memory of `load_h36m` on a full-size synthetic Human3.6M tree (Martinez layout).

Writes 7 subjects x 30 sequences x 4 cameras (~504k frames at 50 fps, as much as the real
h36m.zip) with the test fixture writers, then loads it in a fresh process per configuration (so the
peak RSS is the loader's, not the writer's) and reports wall time and peak RSS
(`resource.getrusage`).  Targets: <= 60 s and <= 4 GiB with the default down-sampling.

    python benchmarks/h36m_loading.py [--out runs/benchmarks/h36m_loading.json] [--data-dir DIR]
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated

import tyro

ROOT = Path(__file__).resolve().parents[1]
SUBJECTS = ("S1", "S5", "S6", "S7", "S8", "S9", "S11")
ACTIONS = (
    "Directions", "Discussion", "Eating", "Greeting", "Phoning", "Photo", "Posing", "Purchases", "Sitting",
    "SittingDown", "Smoking", "Waiting", "WalkDog", "Walking", "WalkTogether",
)
SEQUENCES = tuple(f"{action}{suffix}" for action in ACTIONS for suffix in ("", " 1"))  # 30, as in h36m.zip
TARGET_SECONDS, TARGET_GIB = 60.0, 4.0


def write_tree(root: Path, frames_per_sequence: int) -> dict:
    sys.path.insert(0, str(ROOT / "tests"))
    from fixtures_real_data import write_h36m_martinez_tree

    start = time.perf_counter()
    fixture = write_h36m_martinez_tree(
        root,
        subjects=SUBJECTS,
        sequences=SEQUENCES,
        num_frames=frames_per_sequence,
        missing_views={("S11", "Directions"): ("54138969",)},  # as in the real data
    )
    frames = sum(len(points) for points in fixture.mocap.values())
    size = sum(path.stat().st_size for path in root.rglob("*") if path.is_file())
    return {"frames_50fps": frames, "files": sum(1 for _ in root.rglob("*.h5")), "bytes": size,
            "write_seconds": round(time.perf_counter() - start, 1)}


def measure(data_dir: str, detections: str, stride: int) -> dict:
    """Runs in a child process: import cost, then one `load_h36m`, with peak RSS."""
    import warnings

    import jaxpose.datasets.h36m as h36m

    baseline = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    start = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        dataset = h36m.load_h36m(
            data_dir, detections=detections, train_stride=stride, test_stride=stride, progress=False
        )
    seconds = time.perf_counter() - start
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux
    return {
        "detections": detections,
        "stride": stride,
        "samples": len(dataset),
        "joints": dataset.skeleton.num_joints,
        # Every frame's 2D, kept for the temporal lifter's windows (`FrameContext`).
        "context_frames": len(dataset.context.keypoints2d),
        "context_gib": round((dataset.context.keypoints2d.nbytes + dataset.context.confidence.nbytes) / 2**30, 3),
        "seconds": round(seconds, 2),
        "peak_rss_gib": round(peak / 2**20, 3),
        "rss_after_imports_gib": round(baseline / 2**20, 3),
        "warnings": [str(w.message) for w in caught],
    }


@dataclasses.dataclass(frozen=True)
class Args:
    """The benchmark's flags.  --write and --measure are its own steps, each run in a child process, because
    Linux carries a parent's peak RSS over into the getrusage of a child it forks."""

    out: Path = ROOT / "runs" / "benchmarks" / "h36m_loading.json"
    """The JSON result."""
    data_dir: Annotated[Path | None, tyro.conf.arg(metavar="DIR")] = None
    """A tree written before, to reuse (None: write one to a temporary folder)."""
    frames_per_sequence: int = 2400
    """Frames of every synthetic sequence, 50 fps."""
    write: Annotated[tuple[Path, int] | None, tyro.conf.arg(metavar="DIR FRAMES")] = None
    """Internal, a child process: write the tree to DIR, FRAMES per sequence, and print what was written."""
    measure: Annotated[tuple[str, str, int] | None, tyro.conf.arg(metavar="DIR DETECTIONS STRIDE")] = None
    """Internal, a child process: load the tree in DIR with DETECTIONS at STRIDE and print the time and peak RSS."""


def main(argv: Sequence[str] | None = None) -> None:
    args = tyro.cli(Args, args=argv, description=__doc__, prog="python benchmarks/h36m_loading.py")
    if args.write:
        print(json.dumps(write_tree(*args.write)))
        return
    if args.measure:
        print(json.dumps(measure(*args.measure)))
        return

    def child(*step) -> dict:
        done = subprocess.run([sys.executable, __file__, *map(str, step)], capture_output=True, text=True, check=True)
        return json.loads(done.stdout.strip().splitlines()[-1])

    with tempfile.TemporaryDirectory(prefix="h36m_benchmark_") as scratch:
        data_dir = args.data_dir or Path(scratch)
        tree = {} if args.data_dir else child("--write", data_dir, args.frames_per_sequence)
        print(f"tree: {tree or data_dir}", flush=True)
        runs = []
        for detections, stride in (("sh", 5), ("gt", 5), ("sh", 1)):
            run = child("--measure", data_dir, detections, stride)
            runs.append(run)
            print(f"detections={detections} stride={stride}: {run['samples']} samples in {run['seconds']} s,"
                  f" peak RSS {run['peak_rss_gib']} GiB (after imports {run['rss_after_imports_gib']} GiB),"
                  f" every frame's 2D: {run['context_frames']} frames, {run['context_gib']} GiB", flush=True)
    default = runs[0]
    result = {
        "benchmark": "h36m_loading",
        "machine": {"python": platform.python_version(), "platform": platform.platform(), "cpus": os.cpu_count()},
        "tree": tree,
        "runs": runs,
        "targets": {"seconds": TARGET_SECONDS, "peak_rss_gib": TARGET_GIB},
        "meets_targets": default["seconds"] <= TARGET_SECONDS and default["peak_rss_gib"] <= TARGET_GIB,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"written {args.out}; default run (sh, stride 5) meets targets: {result['meets_targets']}")


if __name__ == "__main__":
    main()
