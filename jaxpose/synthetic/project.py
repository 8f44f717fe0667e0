"""The embedded example rig project: a complete multi-camera recording project written from the simulator.

`write_rig_project(root, config)` writes what a user of `python -m experiments.rig --data.root PROJECT`
brings, so that the rig experiment runs with no download and the tests can drive the whole path::

    PROJECT/
      calibration.toml            the rig, Anipose/Pose2Sim layout, translations in metres
      <recording>/                one folder per recording (a motion family: walking01, reaching02, ...)
        <camera>_json/            OpenPose JSON frames <recording>_<camera>_<frame:012d>_keypoints.json
        ground_truth.npz          points3d f32[N, J', 3] world mm, frames int64[N], joint_names str[J']
      example_truth.json          what was simulated, for tests (see `write_rig_project`)

With `people` P > 1, ground_truth.npz's points3d is f32[N, P, J', 3] (NaN while a person is out of the
scene) and every frame file lists its detections in a random order; example_truth.json's "people_order"
gives each file's entries in file order as codes: k >= 0 person k of that person axis, `FALSE_PERSON`
(-1) a false detection, `PASSER_BY` (-2) the passer-by (in no ground truth).

What is simulated, and how it mirrors real captures, is `jaxpose.synthetic.capture`'s (the rig, its
lenses, the person and a passer-by, the detector) and `jaxpose.synthetic.keypoints`' (a detector's
keypoints, COCO-17 or OpenPose BODY_25, on the simulated body).  This module writes it as a user's
project, as real tools write it:
- OpenPose's compact JSON frames; undetected keypoints are written 0, 0, 0 as OpenPose does.  With one
  person, where a camera sees both the subject and the passer-by, the passer-by is listed first in
  about `second_person_first_rate` of the frames; with several people (or false detections) every
  frame's list is shuffled.
- One camera out of sync: its file numbered f holds the instant of the other cameras' frame
  f + `desync_frames` (it started late for a positive offset); every camera's files are numbered
  0 .. frames_per_recording - 1.

Every random draw comes from generators keyed by (seed, stream, recording, ...), so a seed and a
config write the same project byte for byte.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import tyro

from jaxpose.formats.anipose_toml import write_anipose_toml
from jaxpose.formats.rig_folder import CALIBRATION_TOML, GROUND_TRUTH_NPZ, json_folder, write_ground_truth
from jaxpose.skeleton import COCO_17
from jaxpose.synthetic.capture import (
    MIN_KEYPOINTS, ExampleProjectConfig, ExampleStream, Person, detect, false_people, field_radius2, occlude, passer_by_poses,
    people_bones, people_poses, rig_calibration,
)  # fmt: skip
from jaxpose.synthetic.keypoints import ground_truth_names, keypoints3d, openpose_names

__all__ = ["EXAMPLE_TRUTH_JSON", "ExampleProjectConfig", "main", "write_rig_project"]

EXAMPLE_TRUTH_JSON = "example_truth.json"
# example_truth.json's "people_order" codes besides a person's index on ground_truth.npz's person axis.
FALSE_PERSON = -1
PASSER_BY = -2
# example_truth.json's frame lists, per recording and camera (in the camera's file numbers).
_FRAME_LISTS = ("second_person_frames", "second_person_first_frames", "subject_undetected_frames")


# ----------------------------------------------------------------------------------------------
# Files


def _format_value(value: float) -> str:
    """A number as OpenPose writes it: 6 significant digits, shortest form ("505.232", "0.664216", "0")."""
    return f"{value:.6g}"


def _person_json(keypoints: np.ndarray, scores: np.ndarray) -> str:
    """One `people` entry, compact, in OpenPose's key order; undetected keypoints are 0,0,0."""
    values = []
    for (x, y), score in zip(keypoints.tolist(), scores.tolist()):
        values.append("0,0,0" if score <= 0.0 else f"{_format_value(x)},{_format_value(y)},{_format_value(score)}")
    return (
        '{"person_id":[-1],"pose_keypoints_2d":[' + ",".join(values) + '],"face_keypoints_2d":[],'
        '"hand_left_keypoints_2d":[],"hand_right_keypoints_2d":[],"pose_keypoints_3d":[],'
        '"face_keypoints_3d":[],"hand_left_keypoints_3d":[],"hand_right_keypoints_3d":[]}'
    )


def _clear_previous(root: Path) -> None:
    """Remove an earlier example project at `root` (only what its truth file lists); refuse to write
    into any other non-empty folder."""
    truth_path = root / EXAMPLE_TRUTH_JSON
    if not truth_path.exists():
        if root.exists() and any(root.iterdir()):
            raise FileExistsError(
                f"{root} is not empty and holds no example project ({EXAMPLE_TRUTH_JSON}); choose an empty folder"
            )
        return
    try:
        previous = json.loads(truth_path.read_text())["recordings"]
    except (ValueError, KeyError, TypeError):
        raise FileExistsError(f"{truth_path} is not an example project's truth file; choose an empty folder") from None
    for name in previous:
        if isinstance(name, str) and Path(name).name == name and name not in (".", "..") and (root / name).is_dir():
            shutil.rmtree(root / name)
    (root / CALIBRATION_TOML).unlink(missing_ok=True)
    truth_path.unlink()


def _write_camera(
    folder: Path,
    prefix: str,
    rows: np.ndarray,
    detected: list[tuple[int, Person]],
    order: np.ndarray | np.random.Generator,
    c: int,
) -> dict[str, list]:
    """Write camera c's frame files (file f holds instant index rows[f]) listing the people `detected`
    (each with its code: a person index, `FALSE_PERSON` or `PASSER_BY`); returns its `_FRAME_LISTS` and, where `order` is a generator (the people
    shuffled in every frame), "people_order": each file's codes in file order.  A boolean array
    `order` [T, C] instead lists the passer-by before the subject where it is true."""
    folder.mkdir(parents=True)
    lists: dict[str, list] = {key: [] for key in _FRAME_LISTS}
    shuffle = isinstance(order, np.random.Generator)
    if shuffle:
        lists["people_order"] = []
    for frame, i in enumerate(rows):
        entries = [(code, person) for code, person in detected if person.listed[i, c]]
        if shuffle:
            entries = [entries[j] for j in order.permutation(len(entries))]
        elif len(entries) == 2 and order[i, c]:  # the subject and the passer-by
            entries.reverse()
        codes = [code for code, _ in entries]
        if shuffle:
            lists["people_order"].append(codes)
        if 0 not in codes:
            lists["subject_undetected_frames"].append(frame)
        if PASSER_BY in codes:
            lists["second_person_frames"].append(frame)
            if codes[0] == PASSER_BY and len(codes) > 1:
                lists["second_person_first_frames"].append(frame)
        people = [_person_json(person.keypoints[i, c], person.scores[i, c]) for _, person in entries]
        with open(folder / f"{prefix}_{frame:012d}_keypoints.json", "w", encoding="utf-8") as file:
            file.write('{"version":1.3,"people":[' + ",".join(people) + "]}")
    return lists


def _layout_points(poses: np.ndarray, bones: np.ndarray, layout: str) -> np.ndarray:
    """A person's keypoints f[T, K, 3] (`keypoints3d`) from H36M_17 poses f[T, 17, 3]; NaN while absent."""
    present = np.isfinite(poses).all(axis=(1, 2))
    if present.all():
        return keypoints3d(poses, bones, layout)
    if not present.any():
        return np.full((len(poses), len(openpose_names(layout)), 3), np.nan)
    stand_in = poses[np.argmax(present)]  # any real pose where absent: no degenerate (zero) bones
    points = keypoints3d(np.where(present[:, None, None], poses, stand_in), bones, layout)
    return np.where(present[:, None, None], points, np.nan)


def write_rig_project(root: str | Path, config: ExampleProjectConfig = ExampleProjectConfig()) -> Path:
    """Write the example rig project described in this module's docstring into `root`; returns `root`.

    `root` must be empty or missing, or hold an earlier example project (which is replaced).
    `example_truth.json` records what a test needs: the layout, fps, cameras, image size, the
    desynchronized camera and its offset (file f holds instant f + offset), the ground truth's joint
    names and root, and per recording its motion and, per camera (in that camera's file numbers), the
    frames listing the passer-by, those listing it first, and those not listing the subject.
    """
    root = Path(root)
    _clear_previous(root)
    root.mkdir(parents=True, exist_ok=True)
    truth_path = root / EXAMPLE_TRUTH_JSON
    # Written first, so that an interrupted write can be replaced by the next one (`_clear_previous`).
    truth_path.write_text(json.dumps({"complete": False, "recordings": dict.fromkeys(config.recording_names)}))
    rig = rig_calibration(config)
    write_anipose_toml(root / CALIBRATION_TOML, rig, unit="m")
    max_radius2 = field_radius2(rig.cameras, config.image_size)
    N, C = config.frames_per_recording, config.cameras
    offsets = config.frame_offsets()
    first_instant = int(min(offsets.min(), 0))  # instants simulated: first_instant .. first_instant + T - 1
    T = N + int(offsets.max() - first_instant)
    rows = np.arange(N)[None, :] + offsets[:, None] - first_instant  # [C, N] instant index of each file
    recordings = {}
    bodies = people_bones(config)
    for r, name in enumerate(config.recording_names):
        points = [
            _layout_points(poses, bones, config.layout)
            for poses, bones in zip(people_poses(config, r, bodies, T), bodies)
        ]
        detected = [(p, detect(config, rig, max_radius2, person_points, (r, 0 if p == 0 else p + 1))) for p, person_points in enumerate(points)]
        if config.second_person_rate > 0.0:
            walk, passer_bones, start = passer_by_poses(config, rig.cameras, r, T)
            passer_points = np.full(points[0].shape, np.nan)
            passer_points[start : start + len(walk)] = keypoints3d(walk, passer_bones, config.layout)
            detected.append((PASSER_BY, detect(config, rig, max_radius2, passer_points, (r, 1))))
        if config.occlusion:
            detected = list(zip([code for code, _ in detected], occlude(rig, [person for _, person in detected])))
        if config.false_people_rate > 0.0:
            detected += [(FALSE_PERSON, person) for person in false_people(config, rig, max_radius2, points[0], r)]
        passer_first = config.rng(ExampleStream.ORDER, r).random((T, C)) < config.second_person_first_rate
        record = {"motion": config.motion(r)} | {key: {} for key in _FRAME_LISTS}
        if config.shuffled:
            record["people_order"] = {}
        for c, camera in enumerate(config.camera_names):
            folder = root / name / json_folder(camera)
            order = config.rng(ExampleStream.SHUFFLE, r, c) if config.shuffled else passer_first
            lists = _write_camera(folder, f"{name}_{camera}", rows[c], detected, order, c)
            for key, frames in lists.items():
                record[key][camera] = frames
        truth_points = np.stack(points, axis=1)[-first_instant : -first_instant + N]  # [N, P, K, 3]
        if config.layout == "coco17":
            hips = [COCO_17.joint_names.index("left_hip"), COCO_17.joint_names.index("right_hip")]
            truth_points = np.concatenate([truth_points, truth_points[:, :, hips].mean(2, keepdims=True)], axis=2)
        if config.people == 1:
            truth_points = truth_points[:, 0]  # the single-person layout [N, J', 3]
        write_ground_truth(root / name / GROUND_TRUTH_NPZ, truth_points, np.arange(N), ground_truth_names(config.layout))
        recordings[name] = record
    desync = config.desync_camera >= 0 and config.desync_frames != 0
    truth = {
        "description": "jaxpose's synthetic example rig project: what was simulated, for checking a pipeline on it",
        "complete": True,
        "layout": config.layout,
        "fps": config.fps,
        "frames_per_recording": N,
        "cameras": list(config.camera_names),
        "image_size": list(config.image_size),
        "calibration": CALIBRATION_TOML,
        "calibration_unit": "m",
        "desynchronized_camera": config.camera_names[config.desync_camera] if desync else None,
        "desync_offset_frames": int(config.desync_frames) if desync else 0,
        "frame_offsets": {camera: int(offset) for camera, offset in zip(config.camera_names, offsets)},
        "frame_offset_meaning": (
            "camera c's file numbered f holds the instant of the synchronized cameras' frame f + offset[c]"
        ),
        "ground_truth_joint_names": list(ground_truth_names(config.layout)),
        "ground_truth_root": "pelvis" if config.layout == "coco17" else "MidHip",
        "min_keypoints_per_person": MIN_KEYPOINTS,
        "config": dataclasses.asdict(config),
        "recordings": recordings,
    }
    truth_path.write_text(json.dumps(truth, indent=1) + "\n")
    return root


# ----------------------------------------------------------------------------------------------
# Command line


@dataclasses.dataclass(frozen=True, kw_only=True)
class WriteArgs(ExampleProjectConfig):
    """Write jaxpose's synthetic example rig project (calibration, OpenPose JSON, ground truth)."""

    output: Path
    """The project folder to write: empty or new (an earlier example project there is replaced)."""


def main(argv: Sequence[str] | None = None) -> Path:
    args = tyro.cli(
        WriteArgs, args=argv, prog="python -m jaxpose.synthetic.project", description=WriteArgs.__doc__
    )
    fields = dataclasses.fields(ExampleProjectConfig)
    config = ExampleProjectConfig(**{field.name: getattr(args, field.name) for field in fields})
    began = time.perf_counter()
    try:
        root = write_rig_project(args.output, config)
    except (ValueError, FileExistsError) as error:
        raise SystemExit(f"error: {error}") from None
    files = [path for path in root.rglob("*") if path.is_file()]
    size_mb = sum(path.stat().st_size for path in files) / 1e6
    print(
        f"wrote {root}: {config.recordings} recordings x {config.cameras} cameras x {config.frames_per_recording}"
        f" frames ({len(files)} files, {size_mb:.1f} MB) in {time.perf_counter() - began:.1f} s"
    )
    if config.desync_camera >= 0 and config.desync_frames:
        camera = config.camera_names[config.desync_camera]
        print(
            f"{camera} is {config.desync_frames} frames out of sync: pass"
            f" --data.frame-offsets {camera}={config.desync_frames} or --data.sync auto"
        )
    if config.people == 1:
        print(f"train a lifter on it: python -m experiments.rig --data.root {root}")
    else:
        print(
            f"{config.people} people: ground_truth.npz holds points3d [N, {config.people}, J, 3];"
            f" {EXAMPLE_TRUTH_JSON}'s people_order says who each listed detection is"
        )
    return root


if __name__ == "__main__":
    main()
