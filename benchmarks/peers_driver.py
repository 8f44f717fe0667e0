"""The peers' side of `benchmarks/peers.py`: Pose2Sim and aniposelib run on detections given as files.

    VENV/bin/python benchmarks/peers_driver.py REQUEST.json

Runs with the peers' own virtual environment's python and imports nothing of jaxpose (their
dependencies must not touch jaxpose's).  Everything is exchanged as files, none of them pickled:

- REQUEST.json: {"family": "pose2sim" | "aniposelib", "methods": [...], "calibration": TOML (the
  Anipose / Pose2Sim layout, metres), "fps", "joint_names", "parents" (-1 for the root), "threshold"
  (confidence below which a detection is dropped), "repeats" (calls per method), "times" (JSON path),
  "recordings": [{"name", "inputs" (.npz: keypoints f[F, C, J, 2] pixels as detected, confidence
  f[F, C, J]), "output" (.npz), "work" (a folder)}]}.
- each recording's output .npz: one f64[F, J, 3] array per method, the calibration's world in mm,
  NaN where the method gives nothing.
- "times": {method: [[wall seconds, process CPU seconds] of each call, in order]}, rewritten after
  every call, so that a run stopped at its time limit still tells how far it got.

Pose2Sim (`family` pose2sim, methods "triangulation" and "filtering"): a Pose2Sim trial folder per
recording laid out as Pose2Sim expects it (`Config.toml`, `calibration/`, `pose/camNN_json/` with one
OpenPose JSON per camera and frame), the Config.toml its own template (`Demo_SinglePerson/Config.toml`
of the installed package) with only these changed: the frame rate, `pose_model = "CUSTOM"` with the
detector's joints as a CUSTOM tree, and the filtering's figures neither shown nor saved.  The
triangulation's .trc (Y up: Pose2Sim's turn of the world) is turned back into the calibration's world.

aniposelib (`family` aniposelib): `CameraGroup` from the same TOML (built from its tables in file
order: `CameraGroup.load` sorts the table names as strings, cam_10 before cam_2), detections below
"threshold" as NaN, then `triangulate`, `triangulate_ransac`, `optim_points` (its defaults, started
from `triangulate` as Anipose does) and `optim_points` with the skeleton's limbs as `constraints`.
"""

from __future__ import annotations

import json
import os
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

POSE2SIM_METHODS = ("triangulation", "filtering")
ANIPOSELIB_METHODS = ("triangulate", "triangulate_ransac", "optim_points", "optim_points_limbs")
MM_PER_M = 1000.0


def write_json_atomic(path: Path, value) -> None:
    temporary = path.with_name(path.name + ".tmp")
    temporary.write_text(json.dumps(value))
    os.replace(temporary, path)


class Times:
    """Wall and CPU seconds per call per method, rewritten to disk after each call."""

    def __init__(self, path: Path):
        self.path, self.values = path, {}

    def start(self) -> tuple[float, float]:
        return time.perf_counter(), time.process_time()

    def add(self, method: str, started: tuple[float, float]) -> None:
        self.values.setdefault(method, []).append([time.perf_counter() - started[0], time.process_time() - started[1]])
        write_json_atomic(self.path, self.values)


# ----------------------------------------------------------------------------------------------
# Pose2Sim


def custom_tree(names: list[str], parents: list[int]) -> dict:
    """The skeleton as Pose2Sim's CUSTOM model: nested {"name", "id", "children"} from the root."""

    def node(joint: int) -> dict:
        children = [node(child) for child, parent in enumerate(parents) if parent == joint]
        return {"name": names[joint], "id": joint, **({"children": children} if children else {})}

    return node(parents.index(-1))


def pose2sim_trial(request: dict, recording: dict) -> Path:
    """Lay out one recording as a Pose2Sim trial folder; returns its Config.toml."""
    import Pose2Sim
    import rtoml

    work = Path(recording["work"])
    (work / "calibration").mkdir(parents=True, exist_ok=True)
    (work / "calibration" / "Calib_scene.toml").write_bytes(Path(request["calibration"]).read_bytes())
    config = rtoml.load(Path(Pose2Sim.__file__).parent / "Demo_SinglePerson" / "Config.toml")
    config["project"]["project_dir"] = str(work.resolve())
    config["project"]["frame_rate"] = request["fps"]
    config["pose"]["pose_model"] = "CUSTOM"
    config["pose"]["CUSTOM"] = custom_tree(request["joint_names"], request["parents"])
    config["filtering"]["display_figures"] = False
    config["filtering"]["save_filt_plots"] = False
    (work / "Config.toml").write_text(rtoml.dumps(config))

    data = np.load(recording["inputs"])
    keypoints, confidence = data["keypoints"], data["confidence"]
    F, C, J, _ = keypoints.shape
    for camera in range(C):
        folder = work / "pose" / f"cam{camera + 1:02d}_json"
        folder.mkdir(parents=True, exist_ok=True)
        for frame in range(F):
            seen = confidence[frame, camera] > 0
            people = []
            if seen.any():  # OpenPose writes an undetected joint as 0, 0, 0
                values = np.concatenate([np.where(seen[:, None], keypoints[frame, camera], 0.0), confidence[frame, camera, :, None]], 1)
                people = [{"person_id": [-1], "pose_keypoints_2d": [round(float(v), 3) for v in values.ravel()]}]
            (folder / f"cam{camera + 1:02d}_{frame:06d}.json").write_text(json.dumps({"version": 1.3, "people": people}))
    return work / "Config.toml"


def read_trc(path: Path, names: list[str], frames: int) -> np.ndarray:
    """A Pose2Sim .trc as f64[frames, J, 3] world mm: its Y-up (X, Y, Z) is the world's (y, z, x)."""
    lines = path.read_text().splitlines()
    markers = [name for name in lines[3].split("\t")[2:] if name]
    points = np.full((frames, len(names), 3), np.nan)
    columns = [markers.index(name) for name in names]
    for line in lines[5:]:
        fields = line.split("\t")
        if len(fields) < 2 + 3 * len(markers) or not fields[0].strip():
            continue
        frame = int(float(fields[0]))
        values = np.array([float(v) if v.strip() else np.nan for v in fields[2 : 2 + 3 * len(markers)]]).reshape(-1, 3)
        if 0 <= frame < frames:
            points[frame] = values[columns][:, [2, 0, 1]] * MM_PER_M
    return points


def run_pose2sim(request: dict, times: Times) -> None:
    from Pose2Sim import Pose2Sim

    for recording in request["recordings"]:
        config = pose2sim_trial(request, recording)
        frames = np.load(recording["inputs"])["keypoints"].shape[0]
        pose3d = Path(recording["work"]) / "pose-3d"
        for _ in range(request["repeats"]):
            for method, step in (("triangulation", Pose2Sim.triangulation), ("filtering", Pose2Sim.filtering)):
                if method not in request["methods"]:
                    continue
                started = times.start()
                step(str(config))
                times.add(method, started)
        found = {}
        triangulated = [p for p in pose3d.glob("*.trc") if "filt" not in p.name]
        filtered = [p for p in pose3d.glob("*.trc") if "filt" in p.name]
        if "triangulation" in request["methods"] and triangulated:
            found["triangulation"] = read_trc(triangulated[0], request["joint_names"], frames)
        if "filtering" in request["methods"] and filtered:
            found["filtering"] = read_trc(filtered[0], request["joint_names"], frames)
        np.savez(recording["output"], **found)


# ----------------------------------------------------------------------------------------------
# aniposelib


def camera_group(calibration: Path):
    from aniposelib.cameras import CameraGroup

    document = tomllib.loads(calibration.read_text())
    tables = [table for name, table in document.items() if isinstance(table, dict) and "matrix" in table]
    return CameraGroup.from_dicts(tables)


def run_aniposelib(request: dict, times: Times) -> None:
    group = camera_group(Path(request["calibration"]))
    parents = request["parents"]
    limbs = [[child, parent] for child, parent in enumerate(parents) if parent >= 0]
    for recording in request["recordings"]:
        data = np.load(recording["inputs"])
        keypoints, confidence = data["keypoints"].astype(np.float64), data["confidence"]
        F, C, J, _ = keypoints.shape
        points = np.where((confidence >= request["threshold"])[..., None], keypoints, np.nan).transpose(1, 0, 2, 3)  # [C, F, J, 2]
        found = {}
        for _ in range(request["repeats"]):
            for method in request["methods"]:
                started = times.start()
                if method == "triangulate":
                    result = group.triangulate(points.reshape(C, -1, 2)).reshape(F, J, 3)
                elif method == "triangulate_ransac":
                    result = group.triangulate_ransac(points.reshape(C, -1, 2))[0].reshape(F, J, 3)
                elif method in ("optim_points", "optim_points_limbs"):
                    start = group.triangulate(points.reshape(C, -1, 2)).reshape(F, J, 3)
                    result = group.optim_points(points, start, constraints=limbs if method == "optim_points_limbs" else [])
                else:
                    raise SystemExit(f"peers_driver: unknown aniposelib method {method!r}; expected one of {ANIPOSELIB_METHODS}")
                times.add(method, started)
                found[method] = np.asarray(result, np.float64) * MM_PER_M
        np.savez(recording["output"], **found)


def main(argv: list[str]) -> None:
    if len(argv) != 1:
        raise SystemExit("usage: peers_driver.py REQUEST.json")
    request = json.loads(Path(argv[0]).read_text())
    times = Times(Path(request["times"]))
    if request["family"] == "pose2sim":
        run_pose2sim(request, times)
    elif request["family"] == "aniposelib":
        run_aniposelib(request, times)
    else:
        raise SystemExit(f"peers_driver: unknown family {request['family']!r}; expected pose2sim or aniposelib")


if __name__ == "__main__":
    main(sys.argv[1:])
