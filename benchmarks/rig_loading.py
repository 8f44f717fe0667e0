"""Loading a rig project of Human3.6M's size (`jaxpose.rig.project.load_rig_project`): cold, warm (the
prepared project cached beside the recordings), compilations and peak memory, against the Human3.6M
loader (`experiments.h36m`'s `load_h36m`) on the same data.

Writes the full-size synthetic Human3.6M tree of `benchmarks/h36m_loading.py` (7 subjects x 30 sequences x
4 cameras, ~504k frames at 50 fps), then every subject as rig-project recordings with
`experiments.rig_from_h36m` (a ``detections.npz`` of the Stacked Hourglass 2D and a ``ground_truth.npz``
per sequence, the subject's cameras as an Anipose TOML in metres in each recording folder): 210
recordings, one project.  `--ten-times` adds a project of ten copies of every recording (~5M instants).
Each measurement runs in a fresh process (peak RSS from `resource.getrusage`, so it is that step's;
it counts the pages of memory-mapped files the step touched, which the kernel drops under pressure,
so the peaks of RssAnon, the process's own memory, and RssFile are sampled beside it):

- rig cold: the prepared-project cache removed first; stride 1 (every instant) and stride 5 (the
  development protocol's thinning, `--data.train-stride 5 --data.validation-stride 5`);
- rig warm: the same options again, read from the cache (memory-mapped);
- warm + pseudo-labels: what a run does before its first training step besides compiling it
  (`jaxpose.training.pseudo_labelling.label` of the training part, RANSAC as the rig presets), computed and
  cached beside the prepared project, then again (read from that cache);
- h36m: `load_h36m` of the same tree, stride 1 and 5;
- with `--ten-times`, the ten-times project trained (`experiments.rig`, `--train-steps` steps: loading
  from the cache, the pseudo-labels computed again, training, the report) in a memory cgroup limited to `--memory-limit`
  GiB, page cache included, where the machine lets us make one.

    python benchmarks/rig_loading.py [--ten-times] [--keep DIR] [--out runs/benchmarks/rig_loading.json]

Targets (issue 33, 2 cores): cold <= 30 s and <= 2 GiB, warm <= 10 s, compilations during loading <= 20;
the ten-times project trains within 4 GiB.
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated

import tyro

ROOT = Path(__file__).resolve().parents[1]
TARGETS = {"cold_seconds": 30.0, "cold_peak_rss_gib": 2.0, "warm_seconds": 10.0, "compilations": 20}


def write_rig(h36m_dir: Path, rig_dir: Path) -> dict:
    """Every subject of the tree as recordings "<subject> <sequence>", each with its subject's calibration."""
    sys.path.insert(0, str(ROOT))
    from experiments import rig_from_h36m
    from benchmarks.h36m_loading import SUBJECTS

    start = time.perf_counter()
    rig_dir.mkdir(parents=True)
    for subject in SUBJECTS:
        scratch = rig_dir / f".{subject}"
        rig_from_h36m.write_project(rig_from_h36m.Args(data_dir=h36m_dir, output=scratch, subject=subject))
        for recording in sorted(path for path in scratch.iterdir() if path.is_dir()):
            shutil.copy(scratch / "calibration.toml", recording / "calibration.toml")
            recording.rename(rig_dir / f"{subject} {recording.name}")
        shutil.rmtree(scratch)
    return _sizes(rig_dir) | {"write_seconds": round(time.perf_counter() - start, 1)}


def copy_ten_times(rig_dir: Path, big_dir: Path) -> dict:
    start = time.perf_counter()
    for copy in range(10):
        for recording in sorted(path for path in rig_dir.iterdir() if path.is_dir() and not path.name.startswith(".")):
            shutil.copytree(recording, big_dir / f"{copy} {recording.name}", ignore=shutil.ignore_patterns(".*"))
    return _sizes(big_dir) | {"write_seconds": round(time.perf_counter() - start, 1)}


def _sizes(folder: Path) -> dict:
    files = [path for path in folder.rglob("*") if path.is_file() and ".jaxpose_cache" not in path.parts]
    return {"recordings": sum(1 for path in folder.iterdir() if path.is_dir() and not path.name.startswith(".")),
            "files": len(files), "bytes": sum(path.stat().st_size for path in files)}  # fmt: skip


def measure_rig(rig_dir: str, stride: int, pseudo_labels: bool) -> dict:
    """In a child process: one `load_rig_project` (and the training part's pseudo-labels), its compilations and peak RSS."""
    import jax

    from jaxpose.rig.project import load_rig_project
    from jaxpose.rig.config import RigProjectConfig

    counted = {"/jax/core/compile/jaxpr_to_mlir_module_duration": "lowered", "/jax/core/compile/backend_compile_duration": "compiled"}
    counts = dict.fromkeys(counted.values(), 0)

    def listen(event, _seconds, **_):
        if event in counted:
            counts[counted[event]] += 1

    jax.monitoring.register_event_duration_secs_listener(listen)
    baseline = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    memory = _PeakMemory()
    start = time.perf_counter()
    project = load_rig_project(RigProjectConfig(root=Path(rig_dir), train_stride=stride, validation_stride=stride), progress=False)
    seconds = time.perf_counter() - start
    result = {
        "stride": stride,
        "how": project.prepared.split(" /")[0],
        "train": len(project.train),
        "validation": len(project.validation),
        "instants": sum(r.instants for r in project.recordings),
        "seconds": round(seconds, 2),
        "compilations": dict(counts),
        "peak_rss_gib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20, 3),
        "rss_after_imports_gib": round(baseline / 2**20, 3),
    }
    if pseudo_labels:
        from jaxpose.training import pseudo_labelling
        from jaxpose.training.config import PseudoLabelConfig

        start = time.perf_counter()
        pseudo_labelling.label(project.train, PseudoLabelConfig(method="ransac"))
        result["pseudo_label_seconds"] = round(time.perf_counter() - start, 2)
        result["peak_rss_with_pseudo_labels_gib"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20, 3)
    return result | memory.stop()


class _PeakMemory:
    """This process's peak resident memory by kind, sampled from /proc/self/status every 0.2 s:
    RssAnon (its own, what a memory limit cannot reclaim) and RssFile (pages of memory-mapped files,
    which the kernel drops under pressure)."""

    def __init__(self):
        self.peak = {"RssAnon": 0, "RssFile": 0, "VmRSS": 0}
        self.stopped = threading.Event()
        self.thread = threading.Thread(target=self._sample, daemon=True)
        self.thread.start()

    def _sample(self) -> None:
        while not self.stopped.wait(0.2):
            for line in Path("/proc/self/status").read_text().splitlines():
                name, _, value = line.partition(":")
                if name in self.peak:
                    self.peak[name] = max(self.peak[name], int(value.split()[0]) * 1024)

    def stop(self) -> dict:
        self.stopped.set()
        self.thread.join()
        return {f"peak_{name}_gib": round(value / 2**30, 3) for name, value in self.peak.items()}


def measure_training(rig_dir: str, steps: str, run_dir: str) -> dict:
    """In a child process: `experiments.rig` on the project for `steps` steps (loading from the
    prepared cache, pseudo-labels, training, the report), its time and peak memory by kind."""
    from experiments import rig

    memory = _PeakMemory()
    start = time.perf_counter()
    rig.main(["--data.root", rig_dir, "--train.max-steps", steps, "--run.run-dir", run_dir, "--run.no-progress"])
    return {"seconds": round(time.perf_counter() - start, 1), "steps": int(steps)} | memory.stop() | {
        "peak_rss_gib": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20, 3)
    }


def memory_limited(limit_gib: float) -> tuple[Path | None, str]:
    """A cgroup (v1 memory controller) capping its processes at `limit_gib`, page cache included, or
    None where this machine does not let us make one (then only the peaks are measured)."""
    group = Path(f"/sys/fs/cgroup/memory/jaxpose_rig_loading_{os.getpid()}")
    try:
        group.mkdir()
        (group / "memory.limit_in_bytes").write_text(str(int(limit_gib * 2**30)))
        return group, f"run in a memory cgroup limited to {limit_gib} GiB (page cache included)"
    except OSError as error:
        return None, f"no memory cgroup could be made ({error}): peaks measured, no limit enforced"


@dataclasses.dataclass(frozen=True)
class Args:
    """The benchmark's flags.  --step is its own steps, each run in a child process so that its peak RSS is its own."""

    out: Path = ROOT / "runs" / "benchmarks" / "rig_loading.json"
    """The JSON result."""
    keep: Annotated[Path | None, tyro.conf.arg(metavar="DIR")] = None
    """Write the data here and keep it (None: a temporary folder); data already there is used again."""
    frames_per_sequence: int = 2400
    """Frames of every synthetic sequence, 50 fps."""
    ten_times: bool = False
    """Also a project of ten copies of every recording."""
    train_steps: int = 200
    """With --ten-times: train the ten-times project this many steps under --memory-limit (0: no training)."""
    memory_limit: float = 4.0
    """GiB: the ten-times training's memory cgroup limit (issue 33's target)."""
    step: Annotated[tuple[str, ...], tyro.conf.arg(metavar="KIND [VALUE ...]")] = ()
    """Internal, a child process: one step and its values (KIND: write-h36m, write-rig, copy-ten-times, rig, h36m, train)."""


def main(argv: Sequence[str] | None = None) -> None:
    args = tyro.cli(Args, args=argv, description=__doc__, prog="python benchmarks/rig_loading.py")
    if args.step:
        kind, *values = args.step
        sys.path.insert(0, str(ROOT))
        from benchmarks import h36m_loading

        steps = {
            "write-h36m": lambda folder, frames: h36m_loading.write_tree(Path(folder), int(frames)),
            "write-rig": lambda h36m, rig: write_rig(Path(h36m), Path(rig)),
            "copy-ten-times": lambda rig, big: copy_ten_times(Path(rig), Path(big)),
            "rig": lambda rig, stride, labels: measure_rig(rig, int(stride), labels == "1"),
            "h36m": lambda folder, stride: h36m_loading.measure(folder, "sh", int(stride)),
            "train": measure_training,
        }
        print(json.dumps(steps[kind](*values)))
        return

    def child(*step, group: Path | None = None) -> dict:
        enter = None if group is None else (lambda: (group / "cgroup.procs").write_text(str(os.getpid())))
        command = [sys.executable, __file__, "--step", *map(str, step)]
        done = subprocess.run(command, capture_output=True, text=True, check=False, preexec_fn=enter)
        if done.returncode:
            raise SystemExit(f"step {step} failed (exit {done.returncode}):\n{done.stderr[-4000:]}")
        return json.loads(done.stdout.strip().splitlines()[-1])

    with tempfile.TemporaryDirectory(prefix="rig_loading_") as scratch:
        base = args.keep or Path(scratch)
        h36m_dir, rig_dir, big_dir = base / "h36m", base / "rig", base / "rig_x10"
        data = {}
        if not h36m_dir.exists():
            data["h36m_tree"] = child("write-h36m", h36m_dir, args.frames_per_sequence)
        if not rig_dir.exists():
            data["rig_project"] = child("write-rig", h36m_dir, rig_dir)
        if args.ten_times and not big_dir.exists():
            data["rig_project_x10"] = child("copy-ten-times", rig_dir, big_dir)
        print(f"data: {json.dumps(data)}", flush=True)
        runs = []

        def run(name: str, *step) -> None:
            result = {"name": name} | child(*step)
            runs.append(result)
            print(json.dumps(result), flush=True)

        projects = [("rig", rig_dir)] + ([("rig x10", big_dir)] if args.ten_times else [])
        for label, folder in projects:
            shutil.rmtree(folder / ".jaxpose_cache", ignore_errors=True)
            for stride in (1, 5):
                run(f"{label} cold", "rig", folder, stride, 0)
                run(f"{label} warm", "rig", folder, stride, 0)
            run(f"{label} warm + pseudo-labels", "rig", folder, 1, 1)
            run(f"{label} warm + pseudo-labels again (cached)", "rig", folder, 1, 1)
        for stride in (1, 5):
            run("h36m", "h36m", h36m_dir, stride)
        if args.ten_times and args.train_steps:
            for labels in (big_dir / ".jaxpose_cache").glob("*/pseudo_labels"):
                shutil.rmtree(labels)  # computed inside the limit too
            group, how = memory_limited(args.memory_limit)
            try:
                result = {"name": "rig x10 trains", "memory": how} | child("train", big_dir, args.train_steps, base / "run_x10", group=group)
                if group is not None:
                    result["cgroup_max_usage_gib"] = round(int((group / "memory.max_usage_in_bytes").read_text()) / 2**30, 3)
                    result["cgroup_limit_hits"] = int((group / "memory.failcnt").read_text())
            finally:
                if group is not None:
                    group.rmdir()
            runs.append(result)
            print(json.dumps(result), flush=True)
    cold = next(r for r in runs if r["name"] == "rig cold" and r["stride"] == 1)
    warm = next(r for r in runs if r["name"] == "rig warm" and r["stride"] == 1)
    result = {
        "benchmark": "rig_loading",
        "machine": {
            "python": platform.python_version(), "platform": platform.platform(), "cpus": os.cpu_count(), "load_average": os.getloadavg(),
        },
        "data": data,
        "runs": runs,
        "targets": TARGETS,
        "meets_targets": {
            "cold_seconds": cold["seconds"] <= TARGETS["cold_seconds"],
            "cold_peak_rss_gib": cold["peak_rss_gib"] <= TARGETS["cold_peak_rss_gib"],
            "warm_seconds": warm["seconds"] <= TARGETS["warm_seconds"],
            "compilations": cold["compilations"]["compiled"] <= TARGETS["compilations"],
        },
    }
    trained = next((r for r in runs if r["name"] == "rig x10 trains"), None)
    if trained is not None:  # its own memory (not the page cache of the memory-mapped project) within the limit
        result["meets_targets"]["x10_trains_within_gib"] = trained["peak_RssAnon_gib"] <= args.memory_limit
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"written {args.out}; targets met: {result['meets_targets']}")


if __name__ == "__main__":
    main()
