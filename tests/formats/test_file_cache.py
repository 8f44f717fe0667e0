"""The cache of parsed keypoint files (`jaxpose.formats.file_cache`, as `keypoint_files.read_camera_detections`
uses it): in the file named, reused while the input is unchanged, rebuilt when it changes, a cache that
cannot be read or written only a warning, and nothing written beside the input."""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path

import numpy as np
import pytest

from jaxpose.formats import file_cache
from jaxpose.formats import keypoint_files as kf
from keypoint_writers import check_matches, coco_entry, random_people, write_folder, write_frame


def _cache_file(tmp_path: Path) -> Path:
    """Where the tests keep the cache: a folder of its own, as a rig project's cache."""
    return tmp_path / "cache" / "cam.npz"


def _no_parsing(monkeypatch) -> None:
    def refuse(*args, **kwargs):
        raise AssertionError("parsed again although the cache is valid")

    monkeypatch.setattr(kf, "_parse_chunk", refuse)
    monkeypatch.setattr(kf, "read_coco_results", refuse)
    monkeypatch.setattr(kf, "read_openpose_folder", refuse)


def test_cache_is_reused_and_rebuilt_when_files_change(tmp_path, monkeypatch, caplog):
    folder = tmp_path / "cam01_json"
    written = write_folder(folder, [1, 2, 0, 1])
    first = kf.read_camera_detections(folder, progress=False, cache=_cache_file(tmp_path))
    check_matches(first, written)
    assert _cache_file(tmp_path).is_file()
    assert [p.name for p in _cache_file(tmp_path).parent.iterdir()] == ["cam.npz"]  # no temp file left
    with monkeypatch.context() as patch:
        _no_parsing(patch)
        again = kf.read_camera_detections(folder, progress=False, cache=_cache_file(tmp_path))
    check_matches(again, written)
    assert again.source == str(folder)

    def changed(change) -> kf.CameraDetections:
        change()
        caplog.clear()
        with caplog.at_level("INFO", logger=file_cache.__name__):
            result = kf.read_camera_detections(folder, progress=False, cache=_cache_file(tmp_path))
        assert "changed since" in caplog.text and "reading it again" in caplog.text
        return result

    rng = np.random.default_rng(11)
    written[1] = random_people(rng, 3)  # modified
    check_matches(changed(lambda: write_frame(folder / "clip_000000000001_keypoints.json", written[1])), written)
    written[4] = random_people(rng, 1)  # added
    check_matches(changed(lambda: write_frame(folder / "clip_000000000004_keypoints.json", written[4])), written)
    del written[0]  # removed
    check_matches(changed(lambda: (folder / "clip_000000000000_keypoints.json").unlink()), written)
    written[7] = written.pop(4)  # renamed: the same bytes under another frame number
    moved = lambda: os.replace(folder / "clip_000000000004_keypoints.json", folder / "clip_000000000007_keypoints.json")
    check_matches(changed(moved), written)
    # The key is the files' contents: a file touched, or a folder copied without its times, is still cached.
    path = folder / "clip_000000000002_keypoints.json"
    stat = path.stat()
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))
    with monkeypatch.context() as patch:
        _no_parsing(patch)
        check_matches(kf.read_camera_detections(folder, progress=False, cache=_cache_file(tmp_path)), written)


@pytest.mark.parametrize("kind", ["openpose", "coco"])
def test_same_size_and_time_but_other_bytes_are_read_again(tmp_path, kind, caplog):
    """A file edited in place to the same size with its modification time kept (cp -p, rsync -t, an
    archive extracted) is parsed again: the cache key is the files' contents, not their stat."""
    if kind == "openpose":
        source = tmp_path / "cam01_json"
        write_folder(source, [1, 1, 1])
        path = source / "clip_000000000001_keypoints.json"
    else:
        source = path = tmp_path / "cam01.json"
        people = random_people(np.random.default_rng(5), 2, joints=17)
        path.write_text(json.dumps([coco_entry(3, people[0]), coco_entry(4, people[1])]))
    stale = kf.read_camera_detections(source, progress=False, cache=_cache_file(tmp_path))
    before, stat = path.read_bytes(), path.stat()
    values = before.index(b"keypoints")  # pose_keypoints_2d or keypoints: past OpenPose's "version": 1.3
    digit = next(i for i in range(values, len(before)) if before[i - 1 : i] == b"." and before[i : i + 1].isdigit())
    after = before[:digit] + str((int(before[digit : digit + 1]) + 1) % 10).encode() + before[digit + 1 :]
    path.write_bytes(after)  # the first decimal of the first coordinate changed, in place
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    assert (path.stat().st_size, path.stat().st_mtime_ns) == (stat.st_size, stat.st_mtime_ns)
    with caplog.at_level("INFO", logger=file_cache.__name__):
        again = kf.read_camera_detections(source, progress=False, cache=_cache_file(tmp_path))
    assert "changed since" in caplog.text and "reading it again" in caplog.text
    np.testing.assert_array_equal(again.keypoints, kf.read_camera_detections(source).keypoints)
    assert not np.array_equal(again.keypoints, stale.keypoints)


@pytest.mark.parametrize("damage", [b"not a zip at all", b"PK\x03\x04truncated"])
def test_corrupt_cache_is_ignored_with_a_warning(tmp_path, damage):
    folder = tmp_path / "cam"
    written = write_folder(folder, [1, 1])
    kf.read_camera_detections(folder, progress=False, cache=_cache_file(tmp_path))
    _cache_file(tmp_path).write_bytes(damage)
    with pytest.warns(UserWarning, match=r"ignoring the unreadable cache .*cam\.npz"):
        check_matches(kf.read_camera_detections(folder, progress=False, cache=_cache_file(tmp_path)), written)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # rewritten: read quietly now
        check_matches(kf.read_camera_detections(folder, progress=False, cache=_cache_file(tmp_path)), written)


def test_cache_with_wrong_arrays_is_ignored(tmp_path):
    folder = tmp_path / "cam"
    written = write_folder(folder, [2, 1])
    kf.read_camera_detections(folder, progress=False, cache=_cache_file(tmp_path))
    with np.load(_cache_file(tmp_path)) as data:
        arrays = dict(data)
    arrays["scores"] = arrays["scores"][:, :1]
    np.savez(_cache_file(tmp_path), **arrays)
    with pytest.warns(UserWarning, match="inconsistent shapes"):
        check_matches(kf.read_camera_detections(folder, progress=False, cache=_cache_file(tmp_path)), written)


def test_unwritable_cache_is_a_warning(tmp_path):
    folder = tmp_path / "cam"
    written = write_folder(folder, [1])
    _cache_file(tmp_path).parent.write_text("a file where the cache folder should be")
    with pytest.warns(UserWarning, match="could not write the cache"):
        check_matches(kf.read_camera_detections(folder, progress=False, cache=_cache_file(tmp_path)), written)


def test_interrupted_cache_write_leaves_no_cache(tmp_path, monkeypatch):
    folder = tmp_path / "cam"
    written = write_folder(folder, [1, 1])

    def interrupted(file, **arrays):
        file.write(b"PK\x03\x04 half an archive")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np, "savez", interrupted)
    with pytest.warns(UserWarning, match="No space left on device"):
        check_matches(kf.read_camera_detections(folder, progress=False, cache=_cache_file(tmp_path)), written)
    assert list(_cache_file(tmp_path).parent.iterdir()) == []


def test_the_cache_is_the_file_named_and_nothing_is_written_beside_the_input(tmp_path, monkeypatch):
    """A rig project keeps its parsed JSON in its own cache (`jaxpose.rig.recordings`): the file named, its
    folders made, reused while unchanged; without one nothing is written at all.  The recording's folder
    (a user's) is only read."""
    folder = tmp_path / "recording" / "cam01_json"
    written = write_folder(folder, [1, 2, 0, 1])
    check_matches(kf.read_camera_detections(folder, progress=False), written)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["recording"]
    named = tmp_path / "cache" / "parsed" / "recording" / "cam01_json.npz"
    check_matches(kf.read_camera_detections(folder, progress=False, cache=named), written)
    assert named.is_file()
    with monkeypatch.context() as patch:
        _no_parsing(patch)
        check_matches(kf.read_camera_detections(folder, progress=False, cache=named), written)
    assert sorted(p.name for p in (tmp_path / "recording").iterdir()) == ["cam01_json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cache", "recording"]
