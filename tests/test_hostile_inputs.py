"""A hostile or careless user's folders (issue 42): nothing read from a user's folder runs code, no command
deletes or writes what it was not asked to, and what it refuses is still there afterwards.

Each case here failed before its fix: a crafted pickle in a project's cache ran at the next load; a run
directory pointed at a folder of other files was emptied by --run.overwrite (or silently filled);
`jaxpose.predict` wrote into its own input folder; two recordings of `jaxpose.reconstruct` wrote one file.
"""

from __future__ import annotations

import ast
import dataclasses
import pickle

import numpy as np
import paths
import pytest

from jaxpose.calibration import Calibration
from jaxpose.calibration.scale import MetricScale
from jaxpose.camera import Cameras
from jaxpose.rig import cache
from jaxpose.rig.project import RigProjectConfig, load_rig_project
from jaxpose.synthetic.project import ExampleProjectConfig, write_rig_project

TINY = ExampleProjectConfig(recordings=1, frames_per_recording=40)


class _Payload:
    """Unpickling this creates `marker`: what a crafted file on a shared drive would do."""

    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


def _calibration() -> Calibration:
    rng = np.random.default_rng(0)
    cameras = Cameras(K=rng.normal(size=(3, 3, 3)), R=rng.normal(size=(3, 3, 3)), t=rng.normal(size=(3, 3)), dist=rng.normal(size=(3, 5)))
    scale = MetricScale(mm_per_unit=1.5, measured_mm={"thigh": 420.0}, prior_mm={"thigh": 410.0})
    return Calibration(
        cameras=cameras, camera_names=("a", "b", "c"), image_size=np.array([[1920, 1080]] * 3), reprojection_median_px=rng.random(3),
        reprojection_p90_px=rng.random(3), inlier_fraction=rng.random(3), scale=scale, focal_estimated=True, frames_used=120, seconds=2.5,
    )


def _assert_same(a, b):
    if dataclasses.is_dataclass(a):
        assert type(a) is type(b)
        for field in dataclasses.fields(a):
            _assert_same(getattr(a, field.name), getattr(b, field.name))
    elif isinstance(a, (np.ndarray, np.generic)):
        np.testing.assert_array_equal(a, b)
        assert np.asarray(a).dtype == np.asarray(b).dtype
    else:
        assert a == b and type(a) is type(b)


def test_a_recovered_rig_is_cached_as_json_and_read_back_whole(tmp_path):
    temporary = tmp_path / "prepared-x.tmp-1"
    temporary.mkdir()
    folder = cache.commit(temporary, "x", {"meta": 1}, _calibration())
    assert sorted(p.name for p in folder.iterdir()) == ["project.json", cache.RECOVERED_JSON]
    meta, recovered = cache.read_meta(folder, Calibration)
    assert meta == {"meta": 1}
    _assert_same(_calibration(), recovered)


def test_a_crafted_pickle_in_the_cache_runs_no_code(tmp_path):
    """The reproduction of issue 42 case 4: a pickle placed in PROJECT/.jaxpose_cache/prepared-*/ (where
    the recovered rig used to be pickled) is never opened by the next load; the project loads as before."""
    root = write_rig_project(tmp_path / "project", TINY)
    config = RigProjectConfig(root=root)
    first = load_rig_project(config, progress=False)
    (prepared,) = (root / ".jaxpose_cache").glob(f"{cache.PREFIX}*")
    marker = tmp_path / "code-ran"
    for name in ("recovered.pickle", "project.pickle"):
        (prepared / name).write_bytes(pickle.dumps(_Payload(str(marker))))
    (prepared / "train.evil.npy").write_bytes(pickle.dumps(_Payload(str(marker))))  # an object array's way in
    again = load_rig_project(config, progress=False)
    assert not marker.exists()
    np.testing.assert_array_equal(np.asarray(first.train.keypoints2d), np.asarray(again.train.keypoints2d))


def test_a_damaged_recovered_rig_is_prepared_again(tmp_path):
    temporary = tmp_path / "prepared-x.tmp-1"
    temporary.mkdir()
    folder = cache.commit(temporary, "x", {}, _calibration())
    (folder / cache.RECOVERED_JSON).write_text('{"cameras": {"K": {"ndarray": [1], "dtype": "|O"}}}')
    with pytest.raises(ValueError, match=cache.RECOVERED_JSON):
        cache.read_meta(folder, Calibration)


def _calls(tree: ast.AST) -> list[tuple[str, ast.Call]]:
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            found.append((name, node))
    return found


def test_no_module_unpickles_except_the_named_videopose3d_files():
    """`pickle.load(s)` appears nowhere; `allow_pickle=True` only in `formats.files.load_npz_object`,
    which only the VideoPose3D reader calls (files from the data set folder named on the command line)."""
    unpickling, object_loads = [], []
    for path in sorted((paths.REPO / "jaxpose").rglob("*.py")):
        tree = ast.parse(path.read_text())
        for name, call in _calls(tree):
            if name in ("load", "loads", "Unpickler") and isinstance(call.func, ast.Attribute) and getattr(call.func.value, "id", "") == "pickle":
                unpickling.append(f"{path.name}:{call.lineno}")
            if any(k.arg == "allow_pickle" and not (isinstance(k.value, ast.Constant) and k.value.value is False) for k in call.keywords):
                object_loads.append(path.relative_to(paths.REPO).as_posix())
            if name == "load_npz_object":
                object_loads.append(f"caller {path.relative_to(paths.REPO).as_posix()}")
    assert unpickling == []
    assert sorted(set(object_loads)) == ["caller jaxpose/datasets/videopose3d.py", "jaxpose/formats/files.py"]

