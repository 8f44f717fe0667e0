"""The default `experiments.rig` against `experiments.h36m --preset cpu` on the same data: issue 33's
"the rig run takes no longer than the Human3.6M cpu preset".

Writes the full-size synthetic Human3.6M tree of `benchmarks/h36m_loading.py` with the real training
split's length per sequence (2,600 frames at 50 fps: Human3.6M's 1,559,752 training frames over 4 cameras
and 150 sequences, so that the cpu preset trains its real budget, 70 epochs of ~78k samples), and the same
tree as one rig project (`benchmarks/rig_loading.write_rig`).  Then, one after the other, each in a fresh
process, nothing else in parallel:

- `experiments.rig` with its default preset, cold (the prepared-project cache removed first);
- `experiments.h36m --preset cpu --data.detections sh` (the tree's 2D are Stacked Hourglass detections);
- `experiments.rig` again, warm (the prepared project and its pseudo-labels read from the cache).

Each run's wall time (process start to exit), training samples and steps (from its report.json) and
peak RSS (`os.wait4`; it counts the pages of the memory-mapped project the run touched), and the
ratios of the rig runs' times to the Human3.6M run's.  About an hour on 2 cores.

    python benchmarks/rig_budget.py [--keep DIR] [--flags="--train.max-steps 200"] [--out runs/benchmarks/rig_budget.json]

`--flags` go to every run (a quick check of the script; the budget is only measured without them).
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated

import tyro

from jaxpose.training.run_directory import RunDirectory

ROOT = Path(__file__).resolve().parents[1]

# Human3.6M's training subjects (S1, S5-S8): 1,559,752 frames over 4 cameras and 150 sequences.
TRAINING_FRAMES_PER_SEQUENCE = 2_600


def write_data(base: Path, frames: int) -> dict:
    """The synthetic tree and its rig project in `base` (kept where they already exist), written by
    `benchmarks/rig_loading.py`'s own steps, each in a child process."""
    h36m_dir, rig_dir = base / "h36m", base / "rig"
    written = {}
    if not h36m_dir.exists():
        written["h36m_tree"] = _rig_loading_step("write-h36m", h36m_dir, frames)
    if not rig_dir.exists():
        written["rig_project"] = _rig_loading_step("write-rig", h36m_dir, rig_dir)
    return written


def _rig_loading_step(*step) -> dict:
    command = [sys.executable, str(ROOT / "benchmarks" / "rig_loading.py"), "--step", *map(str, step)]
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode:
        raise SystemExit(f"{step[0]} failed (exit {done.returncode}):\n{done.stderr[-4000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def timed_run(name: str, module: str, arguments: list[str], run_dir: Path, log: Path) -> dict:
    """`python -m module arguments` in a fresh process: wall time, peak RSS, what its report says it trained."""
    command = [sys.executable, "-m", module, *arguments, "--run.run-dir", str(run_dir), "--run.no-progress", "--run.no-tensorboard"]
    start = time.perf_counter()
    with log.open("w") as output:
        process = subprocess.Popen(command, cwd=ROOT, stdout=output, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(process.pid, 0)
    seconds = time.perf_counter() - start
    if os.waitstatus_to_exitcode(status):
        raise SystemExit(f"{name} failed (exit {os.waitstatus_to_exitcode(status)}); see {log}")
    report = json.loads(RunDirectory(run_dir).report_json.read_text())
    batch = report["config"]["train"]["batch_size"]
    return {
        "name": name,
        "command": shlex.join(command[1:]),
        "seconds": round(seconds, 1),
        "steps": report["train_steps"],
        "samples": report["train_steps"] * batch,
        "peak_rss_gib": round(usage.ru_maxrss / 2**20, 2),
        "load_average_after": os.getloadavg(),
    }


def markdown(runs: list[dict], h36m_seconds: float) -> str:
    lines = ["| run | training samples | steps | wall time | against Human3.6M | peak RSS |", "|---|---:|---:|---:|---:|---:|"]
    for run in runs:
        minutes, seconds = divmod(round(run["seconds"]), 60)
        lines.append(
            f"| {run['name']} | {run['samples']:,} | {run['steps']:,} | {minutes} min {seconds:02d} s"
            f" | {run['seconds'] / h36m_seconds:.3f} | {run['peak_rss_gib']} GiB |"
        )
    return "\n".join(lines)


@dataclasses.dataclass(frozen=True)
class Args:
    """The benchmark's flags."""

    out: Path = ROOT / "runs" / "benchmarks" / "rig_budget.json"
    """The JSON result."""
    keep: Annotated[Path | None, tyro.conf.arg(metavar="DIR")] = None
    """Write the data and the runs here and keep them (None: a temporary folder); data already there is used again."""
    frames_per_sequence: int = TRAINING_FRAMES_PER_SEQUENCE
    """Frames of every synthetic sequence, 50 fps."""
    flags: str = ""
    """More flags for every run, one string given with = (e.g. --flags='--train.max-steps 200')."""


def main(argv: Sequence[str] | None = None) -> None:
    args = tyro.cli(Args, args=argv, description=__doc__, prog="python benchmarks/rig_budget.py")

    flags = shlex.split(args.flags)
    with tempfile.TemporaryDirectory(prefix="rig_budget_") as scratch:
        base = args.keep or Path(scratch)
        if (base / "runs").exists():
            raise SystemExit(f"{base / 'runs'} exists: a run there would resume, not be measured; remove it or --keep another folder")
        base.mkdir(parents=True, exist_ok=True)
        data = write_data(base, args.frames_per_sequence)
        shutil.rmtree(base / "rig" / ".jaxpose_cache", ignore_errors=True)
        rig = ["--data.root", str(base / "rig"), *flags]
        h36m = ["--preset", "cpu", "--data.data-dir", str(base / "h36m"), "--data.detections", "sh", *flags]
        plan = [
            ("`experiments.rig`, cold", "experiments.rig", rig, "rig_cold"),
            ("`experiments.h36m --preset cpu --data.detections sh`", "experiments.h36m", h36m, "h36m"),
            ("`experiments.rig`, warm (cache)", "experiments.rig", rig, "rig_warm"),
        ]
        (base / "runs").mkdir()
        runs = []
        for name, module, arguments, folder in plan:
            runs.append(timed_run(name, module, arguments, base / "runs" / folder, base / "runs" / f"{folder}.log"))
            print(json.dumps(runs[-1]), flush=True)
    h36m_seconds = runs[1]["seconds"]
    result = {
        "benchmark": "rig_budget",
        "machine": {"python": platform.python_version(), "platform": platform.platform(), "cpus": os.cpu_count()},
        "frames_per_sequence": args.frames_per_sequence,
        "flags": flags,
        "data": data,
        "runs": runs,
        "rig_over_h36m": {"cold": round(runs[0]["seconds"] / h36m_seconds, 3), "warm": round(runs[2]["seconds"] / h36m_seconds, 3)},
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(markdown(runs, h36m_seconds))
    print(f"written {args.out}; the rig run no longer than the Human3.6M run: cold {runs[0]['seconds'] <= h36m_seconds}, warm {runs[2]['seconds'] <= h36m_seconds}")


if __name__ == "__main__":
    main()
