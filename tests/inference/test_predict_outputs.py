"""What `python -m jaxpose.predict` writes: files replaced only with --overwrite, through temporary files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from detection_helpers import coco_from_h36m, views
from jaxpose import predict


def _coco_results(trained_run, path, image_ids) -> None:
    keypoints = coco_from_h36m(views(trained_run[1])[0][: len(image_ids)])
    triplets = np.concatenate([keypoints, np.full((*keypoints.shape[:2], 1), 0.9)], -1).reshape(len(keypoints), -1)
    path.write_text(json.dumps([{"image_id": i, "keypoints": t.tolist()} for i, t in zip(image_ids, triplets)]))


def _cli(*args) -> np.ndarray:
    return predict.main([str(a) for a in args])


def test_a_second_run_replaces_every_output_only_with_overwrite(trained_run, tmp_path):
    _coco_results(trained_run, tmp_path / "results.json", [1, 2, 3])
    outputs = ["--output", tmp_path / "out" / "poses.npz", "--plot", tmp_path / "plots", "--animation", tmp_path / "clip.gif"]
    common = ["--checkpoint", trained_run[0], "--input", tmp_path / "results.json", "--image-size", 1000, 1000, *outputs]
    first = _cli(*common, "--plot-count", 2)
    written = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file())
    assert [str(p) for p in written] == [
        "clip.gif", "out/poses.npz", "plots/lifting_00000.png", "plots/lifting_00001.png", "results.json",
    ]  # fmt: skip  (no temporary file left behind)
    contents = {p: (tmp_path / p).read_bytes() for p in written}
    with pytest.raises(SystemExit, match=r"poses\.npz: exists; pass --overwrite to replace it"):
        _cli(*common)
    assert {p: (tmp_path / p).read_bytes() for p in written} == contents
    second = _cli(*common, "--plot-count", 2, "--overwrite")
    np.testing.assert_array_equal(first, second)
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file()) == written
    with np.load(tmp_path / "out" / "poses.npz") as data:
        np.testing.assert_array_equal(data["pose3d_mm"], second)
