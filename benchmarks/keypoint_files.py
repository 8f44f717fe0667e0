"""Reading a camera's OpenPose JSON folder with `jaxpose.formats.keypoint_files`: frames per second.

    python -m benchmarks.keypoint_files [--frames 20000] [--rounds 3] [--out runs/benchmarks/keypoint_files.json]

Writes `--frames` synthetic OpenPose frames in OpenPose's own layout (``clip_<12 digits>_keypoints.json``,
compact JSON, version 1.3, 1 or 2 BODY_25 people with 6-significant-digit pixels, empty face / hand / 3D
arrays) into a temporary folder, then reads it, interleaved, per round:

- sequential: one process (``workers=1``), with orjson when importable and with the stdlib json;
- pool: `read_openpose_folder` with ``os.cpu_count()`` worker processes;
- cached: `read_camera_detections` once its cache (a file in the temporary folder) is written (listing and
  hashing every file + one npz).

Prints the median of `--rounds` rounds (wall time, the page cache warm) and ``os.cpu_count()``.
A real project of 4 cameras x 30 min x 60 fps holds ~430k such files.
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import statistics
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import tyro

from jaxpose.formats import fast_json, keypoint_files

ROOT = Path(__file__).resolve().parents[1]
EMPTY_PARTS = ("face_keypoints_2d", "hand_left_keypoints_2d", "hand_right_keypoints_2d", "pose_keypoints_3d",
               "face_keypoints_3d", "hand_left_keypoints_3d", "hand_right_keypoints_3d")  # fmt: skip


def write_frames(folder: Path, count: int, seed: int = 0) -> int:
    """`count` OpenPose BODY_25 frames of 1 or 2 people; returns the bytes written."""
    rng = np.random.default_rng(seed)
    size = 0
    for frame in range(count):
        people = []
        for _ in range(rng.integers(1, 3)):
            xy = rng.uniform(0, 1900, (25, 2))
            score = rng.uniform(0.05, 0.95, (25, 1))
            values = np.concatenate([xy, score], 1)
            values[rng.random(25) < 0.1] = 0.0  # undetected joints are written as 0, 0, 0
            person = {"person_id": [-1], "pose_keypoints_2d": [float(f"{v:.6g}") for v in values.ravel()]}
            people.append(person | {part: [] for part in EMPTY_PARTS})
        text = json.dumps({"version": 1.3, "people": people}, separators=(",", ":"))
        size += (folder / f"clip_{frame:012d}_keypoints.json").write_text(text)
    return size


@dataclasses.dataclass(frozen=True)
class Args:
    """The benchmark's flags."""

    frames: int = 20000
    """OpenPose frames (files) written to the folder read."""
    rounds: int = 3
    """Timed reads of each kind (the median is reported)."""
    out: Path = ROOT / "runs" / "benchmarks" / "keypoint_files.json"
    """The JSON result."""


def main(argv: Sequence[str] | None = None) -> None:
    args = tyro.cli(Args, args=argv, description=__doc__, prog="python -m benchmarks.keypoint_files")
    cores = os.cpu_count()
    orjson_loads = fast_json.orjson_loads

    def sequential_stdlib(folder: Path):
        fast_json.orjson_loads = None  # the fork of a later pool would inherit it: restored below
        try:
            return keypoint_files.read_openpose_folder(folder, progress=False, workers=1)
        finally:
            fast_json.orjson_loads = orjson_loads

    with tempfile.TemporaryDirectory(prefix="keypoint_files_benchmark_") as scratch:
        folder, cache = Path(scratch) / "cam01_json", Path(scratch) / "cache" / "cam01_json.npz"
        folder.mkdir()
        start = time.perf_counter()
        size = write_frames(folder, args.frames)
        print(f"wrote {args.frames} frames ({size / 2**20:.1f} MiB) in {time.perf_counter() - start:.1f} s;"
              f" os.cpu_count() = {cores}; orjson: {orjson_loads is not None}", flush=True)  # fmt: skip
        programs = {
            "sequential": lambda: keypoint_files.read_openpose_folder(folder, progress=False, workers=1),
            "pool": lambda: keypoint_files.read_openpose_folder(folder, progress=False, workers=cores),
            "cached": lambda: keypoint_files.read_camera_detections(folder, progress=False, cache=cache),
        }
        if orjson_loads is not None:
            programs["sequential (stdlib json)"] = lambda: sequential_stdlib(folder)
        reference = keypoint_files.read_camera_detections(folder, progress=False, cache=cache)  # writes the cache
        seconds: dict[str, list[float]] = {name: [] for name in programs}
        for _ in range(args.rounds):
            for name, program in programs.items():
                start = time.perf_counter()
                result = program()
                seconds[name].append(time.perf_counter() - start)
                assert np.array_equal(result.keypoints, reference.keypoints), name
    medians = {name: statistics.median(values) for name, values in seconds.items()}
    rows = {name: {"seconds": round(s, 3), "frames_per_s": round(args.frames / s)} for name, s in medians.items()}
    for name, row in rows.items():
        print(f"{name:>26}: {row['seconds']:7.3f} s  {row['frames_per_s']:>9,} frames/s", flush=True)
    result = {
        "benchmark": "keypoint_files",
        "machine": {"python": platform.python_version(), "platform": platform.platform(), "cpus": cores},
        "frames": args.frames,
        "bytes": size,
        "rounds": args.rounds,
        "orjson": orjson_loads is not None,
        "median": rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"written {args.out}")


if __name__ == "__main__":
    main()
