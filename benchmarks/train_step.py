"""Throughput of the real `train_step` on CPU, against a matmul-only bound and a PyTorch reference.

    python -m benchmarks.train_step [--quick] [--out runs/benchmarks/train_step.json] [--no-torch]
    python -m benchmarks.train_step --loop-steps 60 [--rounds 3] [--loop-tree OTHER_CHECKOUT ...]

Every configuration is the paper's training setup (width 1024, dropout 0.5, BatchNorm, all four
losses on with `output_triangulation_start=0`, Adam) on a synthetic batch of B samples x C views
x 17 joints (`jaxpose.synthetic`, pseudo-labels included), and runs in a fresh worker process,
so that its peak RSS (`resource.getrusage`) is its own.  Per configuration:

- step time (median of `--rounds` timed steps after warm-up), samples/s, view-samples/s, and the
  achieved GFLOP/s with the FLOPs of XLA's cost analysis of the compiled step;
- the efficiency ratio: the time of a jitted program of only the step's matrix products (for
  every Dense layer the forward x @ W, and the backward dX = dY @ W^T and dW = X^T @ dY; no dX
  for the first layer, whose input gradient the step does not compute) over the step's time;
- the geometry share: the time of a jitted program of the step's geometry alone (the four losses,
  the output triangulation, their gradient with respect to the lifter output) over the step's time;
- with PyTorch (the paper configuration, or every one with `--torch-all`): the same step in
  eager PyTorch and under `torch.compile` (`benchmarks.torch_reference`), and the speed ratios.

The programs under comparison run interleaved, one call each per round, in the same process, so
that a change of load on a shared machine hits them alike; besides wall time the table reports
the process CPU time per step (user + system), which a busy machine distorts much less.

`--loop-steps N` times the whole training loop instead (the data stream into the step included): the
synthetic main job (`python -m experiments.synthetic`, batch 256 x 4 views) for N steps, logging every
`LOOP_LOG_EVERY`; the loop's own samples/s of every logged interval but the first (which compiles), median
per run, and the median over `--rounds` runs.  Given several `--loop-tree` checkouts (e.g. two versions of
the loop), their runs alternate, so that a change of load hits them alike.

Workers run with the CPU runtime settings of `TUNED_ENV` (see benchmarks/README.md, "CPU runtime
settings"), unless `--untuned` or the variable is already set in the environment; the JSON records
what was used.  `--untuned-paper` adds a row for the paper configuration without them.
"""

from __future__ import annotations

import dataclasses
import importlib.metadata
import importlib.util
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Annotated

import jax
import jax.numpy as jnp
import numpy as np
import tyro

from jaxpose.training import pseudo_labelling
from jaxpose.training.config import LossConfig, OptimizerConfig
from jaxpose.model import ModelConfig
from jaxpose.data.batch import MultiViewBatch
from jaxpose.synthetic import SyntheticConfig, generate
from jaxpose.losses import total_loss
from jaxpose.training.step import init_train_state, jit_train_step, make_train_step
from jaxpose.triangulation import Method

ROOT = Path(__file__).resolve().parents[1]
PAPER = (8192, 4)  # (samples per batch, views)
FULL_SWEEP = [(256, 4), (1024, 4), (4096, 4), PAPER, (1024, 2), (1024, 8)]
QUICK_SWEEP = [(256, 4), (1024, 4), (256, 2), (256, 8)]
QUICK_TORCH = (256, 4)  # --quick times eager PyTorch here instead of at the paper configuration
NUM_JOINTS = 17
# glibc serves every large buffer of the step with a fresh mmap and munmaps it when freed; on this
# (virtualized) machine filling 4 KiB pages by faults costs more wall time than the step's
# elementwise work, and 2 MiB transparent huge pages cut the faults 512-fold.  XLA's default
# YNNPACK matrix products run ~25% below Eigen's here, so only reductions stay with YNNPACK.
TUNED_ENV = {
    "GLIBC_TUNABLES": "glibc.malloc.hugetlb=1",
    "XLA_FLAGS": "--xla_cpu_experimental_ynn_fusion_type=-individual_dot",
}


def synthetic_batch(batch_size: int, num_views: int, num_joints: int = NUM_JOINTS) -> MultiViewBatch:
    """B samples of the synthetic data set (noisy detections, pseudo-labels by triangulation)."""
    if num_joints != NUM_JOINTS:
        raise ValueError(f"the synthetic data set has {NUM_JOINTS} joints")
    config = SyntheticConfig(num_train_subjects=1, num_test_subjects=0, samples_per_subject=batch_size, num_views=num_views)
    return pseudo_labelling.label(generate(config)).batch(np.arange(batch_size))


PAPER_LOSS = LossConfig(output_triangulation_start=0.0)  # all four terms on from the first step


def paper_step(batch_size: int, num_views: int, model_config=None, loss_config=None):
    """(jitted train step, initial state, device batch, dropout key) at the paper's configuration."""
    # The PyTorch reference implements the RMS input scale (benchmarks/torch_reference.py): the same here,
    # so both sides run one program (the normalization is a negligible part of the step either way).
    model_config = model_config or ModelConfig(input_normalization="intrinsics_scale")
    loss_config = loss_config or PAPER_LOSS
    model = model_config.build(NUM_JOINTS)
    optimizer = OptimizerConfig().build(1000)
    state = init_train_state(model, optimizer, jax.random.key(0))
    step = jit_train_step(make_train_step(model, model_config, optimizer, loss_config, 1000))
    return step, state, jax.device_put(synthetic_batch(batch_size, num_views)), jax.random.key(1)


def dense_kernel_shapes(params) -> list[tuple[int, int]]:
    """(fan_in, fan_out) of every Dense layer, input layer first."""
    leaves = jax.tree_util.tree_leaves_with_path(params)
    return [tuple(leaf.shape) for path, leaf in leaves if jax.tree_util.keystr(path).endswith("['kernel']")]


def matmul_program(kernel_shapes: list[tuple[int, int]], rows: int) -> Callable[[], object]:
    """A jitted program of the matrix products of a train step over `rows` lifter inputs."""
    rng = np.random.default_rng(0)
    operands = [
        tuple(jax.device_put(rng.standard_normal(shape, np.float32)) for shape in ((rows, fan_in), (fan_in, fan_out), (rows, fan_out)))
        for fan_in, fan_out in kernel_shapes
    ]

    @jax.jit
    def products(operands):
        out = []
        for index, (x, w, dy) in enumerate(operands):
            out += [x @ w, x.T @ dy] + ([dy @ w.T] if index else [])
        return out

    return lambda: products(operands)


def geometry_program(batch: MultiViewBatch, loss_config: LossConfig = PAPER_LOSS) -> Callable[[], object]:
    """A jitted program of the step's geometry alone: the four losses (output triangulation included)
    and their gradient with respect to the lifter output, on a lifter output of the batch's shape."""
    weights = loss_config.weights()
    in_camera = jnp.einsum("bcij,bnj->bcni", batch.cameras.R, batch.pseudo3d)
    pred = in_camera - in_camera[:, :, :1] + 20.0  # some error, so that every term has a gradient
    gradient = jax.jit(jax.grad(lambda p, b: total_loss(p, b, weights, loss_config.triangulation)[0]))
    return lambda: gradient(pred, batch)


def timed_rounds(programs: dict[str, Callable[[], object]], rounds: int) -> dict[str, dict[str, list[float]]]:
    """Wall and process-CPU seconds of each program, interleaved: one call of each per round."""
    times = {name: {"wall": [], "cpu": []} for name in programs}
    for _ in range(rounds):
        for name, run in programs.items():
            wall, cpu = time.perf_counter(), time.process_time()
            jax.block_until_ready(run())
            times[name]["wall"].append(time.perf_counter() - wall)
            times[name]["cpu"].append(time.process_time() - cpu)
    return times


def medians(times: dict[str, dict[str, list[float]]]) -> dict[str, dict[str, float]]:
    """The median wall and CPU seconds of each program of `timed_rounds`."""
    return {name: {kind: statistics.median(values) for kind, values in t.items()} for name, t in times.items()}


def peak_rss_gib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # KiB on Linux


def measure(batch_size: int, num_views: int, rounds: int, torch_modes: tuple[str, ...], solver: str = "normal") -> dict:
    """One configuration, in this process (the worker); `solver` of the output triangulation."""
    loss_config = dataclasses.replace(PAPER_LOSS, triangulation=solver)
    step, state, batch, key = paper_step(batch_size, num_views, loss_config=loss_config)
    kernel_shapes = dense_kernel_shapes(state.params)
    compiled = step.lower(state, batch, key, True).compile()
    flops = compiled.cost_analysis()["flops"]
    hlo = compiled.as_text()
    fusions = hlo[hlo.index("\nENTRY") :].count(" fusion(")
    holder = {"state": state}

    def train_step():
        holder["state"], metrics = step(holder["state"], batch, key, True)  # the shares measured, as before the switch
        return holder["state"], metrics

    for _ in range(2):  # the first run also allocates the donated state's new buffers
        jax.block_until_ready(train_step())
    jax_rss = peak_rss_gib()  # before anything else allocates: the step's own peak
    programs = {
        "jax": train_step,
        "matmul": matmul_program(kernel_shapes, batch_size * num_views),
        "geometry": geometry_program(batch, loss_config),
    }
    jax.block_until_ready((programs["matmul"](), programs["geometry"]()))
    torch_warmup_s = {}
    if torch_modes:
        from benchmarks import torch_reference

        arrays = {
            "keypoints2d": batch.keypoints2d, "confidence": batch.confidence, "K": batch.cameras.K, "R": batch.cameras.R,
            "t": batch.cameras.t, "pseudo3d": batch.pseudo3d,
        }
        arrays = {name: np.asarray(value) for name, value in arrays.items()}
        for mode in torch_modes:
            programs[f"torch_{mode}"] = torch_reference.make_step(arrays, compiled=mode == "compile")
            start = time.perf_counter()
            for _ in range(2 if mode == "compile" else 1):  # the first compiled call compiles
                programs[f"torch_{mode}"]()
            torch_warmup_s[mode] = time.perf_counter() - start
    times = timed_rounds(programs, rounds)
    median = medians(times)
    step_s = median["jax"]["wall"]
    record = {
        "batch": batch_size,
        "views": num_views,
        "output_triangulation": solver,
        "rows": batch_size * num_views,
        "rounds": rounds,
        "step_s": step_s,
        "step_cpu_s": median["jax"]["cpu"],
        "samples_per_s": batch_size / step_s,
        "view_samples_per_s": batch_size * num_views / step_s,
        "gflop": flops / 1e9,
        "gflop_per_s": flops / 1e9 / step_s,
        "hlo_fusions": fusions,
        "peak_rss_gib": jax_rss,
        "matmul_s": median["matmul"]["wall"],
        "efficiency": median["matmul"]["wall"] / step_s,
        "efficiency_cpu": median["matmul"]["cpu"] / median["jax"]["cpu"],
        "geometry_s": median["geometry"]["wall"],
        "geometry_share": median["geometry"]["wall"] / step_s,
        "times": times,
    }
    for mode in torch_modes:
        record[f"torch_{mode}_s"] = median[f"torch_{mode}"]["wall"]
        record[f"speedup_vs_{mode}"] = median[f"torch_{mode}"]["wall"] / step_s
        record[f"speedup_vs_{mode}_cpu"] = median[f"torch_{mode}"]["cpu"] / median["jax"]["cpu"]
    if torch_modes:
        record.update(torch_warmup_s=torch_warmup_s, peak_rss_with_torch_gib=peak_rss_gib())
    return record


LOOP_LOG_EVERY = 10


def loop_samples_per_s(tree: Path, steps: int, env: dict[str, str]) -> tuple[float, float]:
    """(median samples/s of the training loop after its first logged interval, the run's CPU seconds): the
    synthetic main job of checkout `tree` for `steps` steps, in a process of its own."""
    import tempfile

    with tempfile.TemporaryDirectory() as scratch:
        run_dir = Path(scratch) / "run"
        command = [sys.executable, "-m", "experiments.synthetic", "--run.run-dir", str(run_dir), "--train.max-steps", str(steps)]
        command += ["--train.log-every", str(LOOP_LOG_EVERY)]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        result = subprocess.run(command, cwd=tree, env={**env, "PYTHONPATH": str(tree)}, capture_output=True, text=True)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if result.returncode != 0:
            raise RuntimeError(f"the training loop of {tree} failed:\n{result.stderr[-4000:]}")
        rates = [json.loads(line)["samples_per_s"] for line in (run_dir / "metrics.jsonl").read_text().splitlines() if '"loss"' in line]
    cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    return statistics.median(rates[1:]), cpu


def loop_benchmark(trees: Sequence[Path], steps: int, rounds: int, env: dict[str, str]) -> dict:
    """`loop_samples_per_s` of every tree, `rounds` times, alternating."""
    runs: dict[str, list[tuple[float, float]]] = {str(tree): [] for tree in trees}
    for _ in range(rounds):
        for tree in trees:
            runs[str(tree)].append(loop_samples_per_s(tree, steps, env))
            print(f"{tree}: {runs[str(tree)][-1][0]:.0f} samples/s", flush=True)
    return {
        tree: {"samples_per_s": [rate for rate, _ in values], "cpu_s": [cpu for _, cpu in values],
               "median_samples_per_s": statistics.median(rate for rate, _ in values)}
        for tree, values in runs.items()
    }  # fmt: skip


def package_version(name: str) -> str | None:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return None


def environment() -> dict:
    cpu_model = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("model name")), platform.processor())
    return {
        "cpu_count": os.cpu_count(),
        "nproc": len(os.sched_getaffinity(0)),
        "cpu_model": cpu_model,
        "memory_gib": os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30,
        "python": platform.python_version(),
        **{package: package_version(package) for package in ("jax", "jaxlib", "flax", "optax", "torch")},
        "XLA_FLAGS": os.environ.get("XLA_FLAGS", ""),
        "GLIBC_TUNABLES": os.environ.get("GLIBC_TUNABLES", ""),
        "load_average": os.getloadavg(),
    }


def run_worker(
    batch_size: int, num_views: int, rounds: int, torch_modes: tuple[str, ...], env: dict[str, str], solver: str
) -> dict:
    command = [sys.executable, "-m", "benchmarks.train_step", "--worker", f"{batch_size},{num_views}", "--rounds", str(rounds)]
    command += ["--solver", solver]
    if torch_modes:
        command += ["--worker-torch", ",".join(torch_modes)]
    result = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True)
    if result.returncode != 0:
        raise RuntimeError(f"worker {batch_size}x{num_views} failed:\n{result.stderr[-4000:]}")
    return json.loads(result.stdout.strip().splitlines()[-1])


def runtime_name(env: dict[str, str]) -> str:
    return "tuned" if env == TUNED_ENV else "default" if not any(env.values()) else "custom"


def markdown(records: list[dict]) -> str:
    lines = [
        "| B | C | runtime | step s (wall) | step s (CPU) | samples/s | view-samples/s | GFLOP/s | efficiency (wall / CPU) | geometry share | peak RSS GiB | vs torch eager (wall / CPU) | vs torch.compile (wall / CPU) |",
        "|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in records:
        torch_cells = [
            f"{r[f'speedup_vs_{mode}']:.2f}x / {r[f'speedup_vs_{mode}_cpu']:.2f}x ({r[f'torch_{mode}_s']:.2f} s)" if f"torch_{mode}_s" in r else ""
            for mode in ("eager", "compile")
        ]
        lines.append(
            f"| {r['batch']} | {r['views']} | {runtime_name(r.get('runtime_env', {}))} | {r['step_s']:.3f} | {r['step_cpu_s']:.3f} | {r['samples_per_s']:.0f} |"
            f" {r['view_samples_per_s']:.0f} | {r['gflop_per_s']:.0f} | {r['efficiency']:.2f} / {r['efficiency_cpu']:.2f} |"
            f" {r['geometry_share']:.1%} |"
            f" {r['peak_rss_gib']:.2f} | {torch_cells[0]} | {torch_cells[1]} |"
        )
    return "\n".join(lines)


@dataclasses.dataclass(frozen=True)
class Args:
    """The benchmark's flags.  --worker and --worker-torch make this process one configuration's worker."""

    quick: bool = False
    """Smaller sweep, PyTorch eager only, at B=256 (under 2 minutes)."""
    out: Path = ROOT / "runs" / "benchmarks" / "train_step.json"
    """JSON results (a markdown table is written beside it)."""
    rounds: int = 5
    """Timed steps per program after warm-up (the median is reported)."""
    torch: bool = True
    """Time the PyTorch reference (--no-torch skips it)."""
    torch_all: bool = False
    """Time PyTorch at every configuration."""
    untuned: bool = False
    """Run the workers without TUNED_ENV."""
    untuned_paper: bool = False
    """Add the paper configuration without TUNED_ENV."""
    solver: Method = LossConfig.triangulation
    """Solver of the output triangulation in the step (the training default: normal)."""
    loop_steps: int = 0
    """Time the training loop over this many steps instead of the sweep (see above; 0: the sweep)."""
    loop_tree: tuple[Path, ...] = (ROOT,)
    """With --loop-steps: the checkouts whose loops are timed, alternately (default: this one)."""
    worker: Annotated[str | None, tyro.conf.arg(metavar="B,C")] = None
    """Internal, a worker process: measure the configuration of B samples x C views and print it as JSON."""
    worker_torch: Annotated[str, tyro.conf.arg(metavar="MODES")] = ""
    """Internal, with --worker: the PyTorch modes timed beside it, comma-separated (eager, compile)."""


def main(argv: Sequence[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = tyro.cli(Args, args=argv, description=__doc__, prog="python -m benchmarks.train_step")

    if args.worker:
        batch_size, num_views = (int(v) for v in args.worker.split(","))
        torch_modes = tuple(filter(None, args.worker_torch.split(",")))
        print(json.dumps(measure(batch_size, num_views, args.rounds, torch_modes, args.solver)))
        return

    if args.loop_steps:
        info = environment()
        env = dict(os.environ) if args.untuned else {**TUNED_ENV, **os.environ}
        loops = loop_benchmark(args.loop_tree, args.loop_steps, args.rounds, env)
        info["load_average_end"] = os.getloadavg()
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"environment": info, "loop_steps": args.loop_steps, "loops": loops}, indent=1))
        for tree, result in loops.items():
            print(f"{tree}: median {result['median_samples_per_s']:.0f} samples/s over {args.rounds} runs"
                  f" ({', '.join(f'{rate:.0f}' for rate in result['samples_per_s'])}), {os.cpu_count()} cores")  # fmt: skip
        return

    torch_modes = () if not args.torch else ("eager",) if args.quick else ("eager", "compile")
    if torch_modes and importlib.util.find_spec("torch") is None:
        torch_modes = ()
        print("PyTorch not importable: no reference timings (pip install -e '.[bench]')", file=sys.stderr)
    plain = dict(os.environ)
    tuned = plain if args.untuned else {**TUNED_ENV, **plain}
    sweep, torch_at = (QUICK_SWEEP, QUICK_TORCH) if args.quick else (FULL_SWEEP, PAPER)
    runs = [(config, tuned) for config in sweep] + ([(PAPER, plain)] if args.untuned_paper else [])
    start = time.perf_counter()
    info = environment()
    records = []
    for (batch_size, num_views), env in runs:
        timed_torch = env is tuned and (args.torch_all or (batch_size, num_views) == torch_at)
        record = run_worker(batch_size, num_views, args.rounds, torch_modes if timed_torch else (), env, args.solver)
        record["runtime_env"] = {name: env.get(name, "") for name in TUNED_ENV}
        records.append(record)
        print(markdown([record]).splitlines()[-1], flush=True)
    info["load_average_end"] = os.getloadavg()
    result = {
        "command": " ".join([Path(sys.executable).name, "-m", "benchmarks.train_step", *argv]),
        "environment": info,
        "total_s": time.perf_counter() - start,
        "results": records,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1))
    table = markdown(records)
    args.out.with_suffix(".md").write_text(table + "\n")
    print(f"\n{table}\n\nwritten to {args.out} ({result['total_s']:.0f} s)")


if __name__ == "__main__":
    main()
