"""Loading a rig project at scale (`jaxpose.rig.project`, `jaxpose.rig.cache`): compilations that do
not grow with the recordings, the prepared project cached and memory-mapped, a calibration's unit
checked against the people in view, and one-line refusals of folder names and links that break loading."""

import dataclasses
import os
import pathlib
import re
import shutil

import jax
import numpy as np
import pytest

from compilations import compilations
from jaxpose.training import pseudo_labelling
from jaxpose.training.config import PseudoLabelConfig
from jaxpose.formats.errors import DataFormatError
from jaxpose.rig.project import load_rig_project
from jaxpose.rig.config import RigProjectConfig
from jaxpose.synthetic.project import ExampleProjectConfig, write_rig_project

TINY = ExampleProjectConfig(recordings=2, frames_per_recording=60)


def _project(root, recordings: int, lengths) -> object:
    """An example project whose recordings have the given numbers of frames (later frames deleted)."""
    root = write_rig_project(root, dataclasses.replace(TINY, recordings=recordings, frames_per_recording=max(lengths)))
    for recording, length in zip(sorted(p for p in root.iterdir() if p.is_dir()), lengths, strict=True):
        for camera in (p for p in recording.iterdir() if p.is_dir()):
            for frame in sorted(camera.glob("*.json"))[length:]:
                frame.unlink()
    return root


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    return _project(tmp_path_factory.mktemp("two") / "project", 2, (60, 45))


def test_loading_compiles_no_more_for_more_and_longer_recordings(small, tmp_path):
    """After a project of 2 recordings, one of 8 recordings of other lengths (and other counts of people
    per frame) compiles at most 10 programs anew: loading (frame offsets estimated) compiles a fixed set
    of programs, not one per recording and shape, so a fresh run of either compiles as much (within 10)."""
    many = _project(tmp_path / "eight", 8, (30, 35, 41, 46, 52, 57, 63, 68))
    with compilations() as two:
        load_rig_project(RigProjectConfig(root=small, sync="auto", max_sync_offset=3), progress=False)
    with compilations() as eight:
        data = load_rig_project(RigProjectConfig(root=many, sync="auto", max_sync_offset=3), progress=False)
    assert len(data.recordings) == 8
    print(f"compilations of 2 recordings {two}, then of 8 recordings {eight}")
    assert eight["lowered"] <= 10 and eight["compiled"] <= 10, (two, eight)


def _prepared_folders(root) -> list[str]:
    return sorted(p.name for p in (root / ".jaxpose_cache").iterdir() if p.name.startswith("prepared-"))


def test_the_prepared_project_is_cached_and_memory_mapped(small, tmp_path):
    root = tmp_path / "project"
    shutil.copytree(small, root, ignore=shutil.ignore_patterns(".jaxpose_cache"))
    config = RigProjectConfig(root=root, frame_offsets=("cam03=3",))
    cold = load_rig_project(config, progress=False)
    assert cold.prepared.startswith("prepared and written to the cache")
    warm = load_rig_project(config, progress=False)
    assert warm.prepared.startswith("read from the cache") and isinstance(warm.train.samples.keypoints2d, np.memmap)
    for part in ("train", "validation"):  # every per-sample array, labels and context rows too
        jax.tree.map(np.testing.assert_array_equal, getattr(cold, part).samples, getattr(warm, part).samples)
    assert cold.recordings == warm.recordings and cold.ground_truth_joints == warm.ground_truth_joints
    # The parsed JSON is cached in the project's cache, none inside the recording folders.
    assert (root / ".jaxpose_cache" / "parsed").is_dir() and not [p for p in root.glob("*/**/.jaxpose_cache")]
    # Another split reads the same prepared folder; another option that changes the arrays prepares a
    # second one, and the first stays (another command's options select it).
    (first,) = _prepared_folders(root)
    assert load_rig_project(dataclasses.replace(config, train_stride=2, validation_recordings=("walking01",)), progress=False).prepared.startswith("read from the cache")
    assert load_rig_project(dataclasses.replace(config, min_confidence=0.2), progress=False).prepared.startswith("prepared and written")
    assert first in _prepared_folders(root) and len(_prepared_folders(root)) == 2
    assert load_rig_project(config, progress=False).prepared.startswith("read from the cache")
    # One frame edited in place to the same size with its times put back: prepared again, and the two
    # folders made from the frame as it was, which no options can read any more, are removed; so is a
    # folder of an earlier jaxpose (no input digests: its version is in no key made now).
    earlier = root / ".jaxpose_cache" / ("prepared-" + "e" * 32)  # named as the cache names its folders
    earlier.mkdir()
    (earlier / "project.json").write_text('{"layout": "coco17"}')
    frame = sorted((sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))[0] / "cam01_json").glob("*.json"))[3]
    times = frame.stat()
    text = frame.read_text()
    digit = re.search(r"[1-8]", text).start()
    frame.write_text(text[:digit] + str(int(text[digit]) + 1) + text[digit + 1 :])
    os.utime(frame, ns=(times.st_atime_ns, times.st_mtime_ns))
    assert frame.stat().st_size == times.st_size
    assert load_rig_project(config, progress=False).prepared.startswith("prepared and written")
    assert len(_prepared_folders(root)) == 1 and first not in _prepared_folders(root)


def test_a_split_is_a_selection_of_the_prepared_instants(small, tmp_path):
    """The split and the strides are applied to every prepared instant: each part is the rows the split
    rule names (checked by hand on the instants of every recording), with every instant as its context;
    the held-out recordings, the fractions and the strides read one prepared folder."""
    root = tmp_path / "project"
    shutil.copytree(small, root, ignore=shutil.ignore_patterns(".jaxpose_cache"))
    base = RigProjectConfig(root=root, frame_offsets=("cam03=3",))
    names = tuple(p.name for p in sorted(root.iterdir()) if p.is_dir() and not p.name.startswith("."))
    every = load_rig_project(dataclasses.replace(base, validation_recordings=names), progress=False)
    assert len(every.train) == 0 and len(every.validation) == sum(r.instants for r in every.recordings)
    assert isinstance(every.validation.samples.keypoints2d, np.memmap)  # every instant: the prepared arrays themselves
    whole = every.validation
    for config in (
        dataclasses.replace(base, train_stride=3, validation_stride=2),
        dataclasses.replace(base, validation_recordings=names[:1], train_stride=2),
        dataclasses.replace(base, validation_fraction=0.5),
    ):
        project = load_rig_project(config, progress=False)
        assert project.prepared.startswith("read from the cache")
        expected = {"train": [], "validation": []}
        for name in names:
            rows = np.flatnonzero(whole.samples.labels["recording"] == name)
            n = len(rows)
            held = np.ones(n, bool) if name in config.validation_recordings else (
                np.zeros(n, bool) if config.validation_recordings else np.arange(n) >= int(round(n * (1 - config.validation_fraction))))
            position = np.arange(n)
            expected["train"] += rows[~held & (position % config.train_stride == 0)].tolist()
            expected["validation"] += rows[held & (position % config.validation_stride == 0)].tolist()
        for part, rows in expected.items():
            dataset = getattr(project, part)
            np.testing.assert_array_equal(dataset.samples.keypoints2d, whole.samples.keypoints2d[rows])
            np.testing.assert_array_equal(dataset.samples.confidence, whole.samples.confidence[rows])
            np.testing.assert_array_equal(dataset.samples.labels["frame"], whole.samples.labels["frame"][rows])
            np.testing.assert_array_equal(dataset.samples.target3d, whole.samples.target3d[rows])
            # A window of 3 frames: the instant and its neighbours of the same recording, from every instant.
            if len(rows):
                windows, _ = dataset.windows(np.arange(len(rows)), 3)
                np.testing.assert_array_equal(windows[:, :, 1], whole.samples.keypoints2d[rows])
                for row, window in zip(rows, windows):
                    same = np.flatnonzero(whole.samples.labels["recording"] == whole.samples.labels["recording"][row])
                    neighbours = np.clip(np.array([row - 1, row + 1]), same[0], same[-1])
                    np.testing.assert_array_equal(window[:, [0, 2]], np.moveaxis(whole.samples.keypoints2d[neighbours], 0, 1))
    assert len(_prepared_folders(root)) == 1


def test_the_pseudo_labels_of_a_prepared_project_are_cached_beside_it(small, tmp_path):
    root = tmp_path / "project"
    shutil.copytree(small, root, ignore=shutil.ignore_patterns(".jaxpose_cache"))
    train = load_rig_project(RigProjectConfig(root=root, frame_offsets=("cam03=3",)), progress=False).train
    ransac = PseudoLabelConfig(method="ransac")
    computed = pseudo_labelling.label(train, ransac)
    cached = pseudo_labelling.label(train, ransac)
    in_memory = pseudo_labelling.label(train.with_samples(keypoints2d=np.array(train.samples.keypoints2d)), ransac)
    assert isinstance(cached.samples.pseudo3d, np.memmap) and not isinstance(in_memory.samples.pseudo3d, np.memmap)
    jax.tree.map(np.testing.assert_array_equal, computed.samples, cached.samples)  # the labels, and every other array
    jax.tree.map(np.testing.assert_array_equal, in_memory.samples, cached.samples)
    svd = pseudo_labelling.label(train, PseudoLabelConfig(method="svd"))  # another method: its own labels
    assert svd.samples.detection_weight is None and not np.array_equal(svd.samples.pseudo3d, cached.samples.pseudo3d)
    assert len(list(pathlib.Path(train.samples.keypoints2d.filename).parent.glob("pseudo_labels/train-*"))) == 2


def test_projects_sharing_a_cache_folder_keep_their_parsed_recordings_apart(small, tmp_path, caplog):
    """Two projects whose recordings have the same names, one --data.cache-dir: each recording's parsed JSON
    is kept under its own folder's name, so that preparing the first again (another --data.min-confidence)
    reads its parsed files instead of parsing again over what the second left there."""
    first, second = tmp_path / "first", tmp_path / "second"
    shutil.copytree(small, first, ignore=shutil.ignore_patterns(".jaxpose_cache"))
    shutil.copytree(small, second, ignore=shutil.ignore_patterns(".jaxpose_cache"))
    shared = tmp_path / "cache"
    for root in (first, second):
        load_rig_project(RigProjectConfig(root=root, frame_offsets=("cam03=3",), cache_dir=shared), progress=False)
    names = sorted(recording.name for recording in first.iterdir() if recording.is_dir())
    parsed = sorted(folder.name for folder in (shared / "parsed").iterdir())
    assert len(parsed) == 2 * len(names) and all(any(folder.startswith(f"{name}-") for folder in parsed) for name in names)
    with caplog.at_level("INFO"):
        load_rig_project(RigProjectConfig(root=first, frame_offsets=("cam03=3",), cache_dir=shared, min_confidence=0.2), progress=False)
    assert "changed since" not in caplog.text and caplog.text.count("from the cache") >= 4 * len(names)  # every camera's parsed file


def test_a_calibration_in_centimetres_without_its_unit_is_refused(small, tmp_path):
    """Issue 34 item 3: the example's calibration written in centimetres with no unit stated reads as
    millimetres (its rig is then 1 m across: plausible); the people in view, 10 times too small, say otherwise."""
    root = tmp_path / "project"
    shutil.copytree(small, root, ignore=shutil.ignore_patterns(".jaxpose_cache"))
    text = (root / "calibration.toml").read_text()

    def in_centimetres(match):
        return "translation = [ " + ", ".join(f"{100 * float(v):.6f}" for v in match.group(1).split(",")) + " ]"

    text = re.sub(r"translation = \[ (.*) \]", in_centimetres, text)
    (root / "calibration.toml").write_text(text.split("[metadata]")[0])
    with pytest.raises(DataFormatError) as refused:
        load_rig_project(RigProjectConfig(root=root, frame_offsets=("cam03=3",)), progress=False)
    message = str(refused.value)
    assert "\n" not in message and message.startswith(str(root / "calibration.toml"))
    assert "likely in 'cm'" in message and "--data.calibration-unit" in message
    # Said so, it is the example's rig: the same person chosen in every view and instant.
    data = load_rig_project(RigProjectConfig(root=root, frame_offsets=("cam03=3",), calibration_unit="cm"), progress=False)
    metres = load_rig_project(RigProjectConfig(root=small, frame_offsets=("cam03=3",)), progress=False)
    np.testing.assert_array_equal(data.train.samples.confidence, metres.train.samples.confidence)


def test_a_folder_name_that_is_not_utf8_is_refused_in_one_line(small, tmp_path):
    root = tmp_path / "project"
    shutil.copytree(small, root, ignore=shutil.ignore_patterns(".jaxpose_cache"))
    first = sorted(p for p in root.iterdir() if p.is_dir())[0]
    first.rename(os.fsdecode(os.fsencode(first) + b"\xff"))
    with pytest.raises(DataFormatError, match=rf"^{re.escape(str(first))}\\xff: expected a recording name in UTF-8[^\n]*$"):
        load_rig_project(RigProjectConfig(root=root), progress=False)


@pytest.mark.parametrize("where", ["project", "frames"])
def test_a_symbolic_link_that_loops_is_refused_in_one_line(small, tmp_path, where):
    root = tmp_path / "project"
    shutil.copytree(small, root, ignore=shutil.ignore_patterns(".jaxpose_cache"))
    if where == "project":
        link = root / "again"
        link.symlink_to(root)  # the project inside itself
    else:
        link = sorted(p for p in root.iterdir() if p.is_dir())[0] / "cam02_json" / "x_000500.json"
        link.symlink_to(link.parent / "y.json")
        (link.parent / "y.json").symlink_to(link)
    with pytest.raises(DataFormatError, match=rf"^{re.escape(str(link))}: expected .*a symbolic link that loops[^\n]*$"):
        load_rig_project(RigProjectConfig(root=root), progress=False)


@pytest.mark.slow  # two whole runs per case, ~110 s on 2 cores
@pytest.mark.trains
@pytest.mark.parametrize("held_out", ["fraction", "recordings"])
def test_a_one_step_run_compiles_as_much_for_eight_recordings_as_for_two(small, tmp_path, held_out):
    """Issue 41: the programs a one-step `experiments.rig` run lowers (loading, pseudo-labels, the step, the
    periodic and final evaluation, the report) do not follow the number or lengths of the recordings: the
    in-memory caches cleared before each run, 2 recordings and 8 of other lengths lower as many programs, with
    the last 20% of each recording held out or whole recordings (1 of 2, 3 of 8).  (Lowering precedes every
    compilation, also one JAX's persistent cache then serves.)"""
    from experiments import rig

    many = _project(tmp_path / "eight", 8, (30, 35, 41, 46, 52, 57, 63, 68))
    two = tmp_path / "two"  # both prepared here: the shared `small` may hold a prepared project of any split
    shutil.copytree(small, two, ignore=shutil.ignore_patterns(".jaxpose_cache"))
    counts = {}
    for name, root, held in (("two", two, 1), ("eight", many, 3)):
        recordings = sorted(p.name for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))
        split = ["--data.validation-recordings", *recordings[:held]] if held_out == "recordings" else []
        jax.clear_caches()
        with compilations() as found:
            rig.main([
                "--data.root", str(root), "--run.run-dir", str(tmp_path / f"run_{name}"), "--train.max-steps", "1",
                "--model.width", "64", "--train.batch-size", "16", "--run.no-progress", "--run.plot-samples", "0",
                "--run.no-tensorboard", *split,
            ])  # fmt: skip
        counts[name] = found["lowered"]
    assert counts["two"] == counts["eight"], counts


def test_a_calibration_of_any_name_is_in_the_cache_key(small, tmp_path):
    """Issue 52 defect 9: a calibration named ``.calibration.toml`` is the one used; moving a camera by 500 mm
    in it must prepare again with the camera moved, not read the arrays of the rig as it was."""
    root = tmp_path / "project"
    shutil.copytree(small, root, ignore=shutil.ignore_patterns(".jaxpose_cache"))
    hidden = root / ".calibration.toml"
    (root / "calibration.toml").rename(hidden)
    config = RigProjectConfig(root=root, frame_offsets=("cam03=3",))
    before = load_rig_project(config, progress=False)
    text = hidden.read_text()
    first = re.search(r"translation = \[ ([-0-9.e]+),", text)  # cam01's, in metres
    hidden.write_text(text[: first.start(1)] + repr(float(first.group(1)) + 0.5) + text[first.end(1) :])
    after = load_rig_project(config, progress=False)
    assert after.prepared.startswith("prepared and written")
    moved = np.zeros_like(np.asarray(before.validation.rigs.t))
    moved[0, 0, 0] = 500.0  # rig 0, camera cam01 (the first in view order), x
    np.testing.assert_allclose(np.asarray(after.validation.rigs.t) - np.asarray(before.validation.rigs.t), moved, atol=1e-3)


def test_every_file_loading_opens_is_in_the_cache_key(small, tmp_path):
    """The cache key's files are what finding the project found (`cache._input_files`): every file that a
    cold load opens outside its cache, calibrations of any name, the project's and a recording's own, is
    among them, so that no file read can change without a miss."""
    import sys

    from jaxpose.rig import cache
    from jaxpose.rig.recordings import find_project

    root = tmp_path / "project"
    shutil.copytree(small, root, ignore=shutil.ignore_patterns(".jaxpose_cache"))
    recording = sorted(p for p in root.iterdir() if p.is_dir())[0]
    shutil.copy(root / "calibration.toml", recording / ".own.toml")  # a recording's own rig, hidden too
    (root / "calibration.toml").rename(root / ".calibration.toml")
    config = RigProjectConfig(root=root, frame_offsets=("cam03=3",))
    opened: list[pathlib.Path] = []
    watching = [True]

    def hook(event, args):
        if watching and event == "open" and isinstance(args[0], (str, os.PathLike)):
            opened.append(pathlib.Path(os.fsdecode(args[0])))

    sys.addaudithook(hook)  # an audit hook cannot be removed: `watching` ends it
    try:
        load_rig_project(config, progress=False)
    finally:
        watching.clear()
    found = find_project(root, (), None)
    keyed = {path.resolve() for files in cache._input_files(config, found).values() for path in files}
    read = {path.resolve() for path in opened if path.resolve().is_relative_to(root.resolve()) and path.resolve().is_file()}
    read = {path for path in read if not path.is_relative_to(config.cache.resolve())}
    assert root.resolve() / ".calibration.toml" in read and recording.resolve() / ".own.toml" in read
    assert read <= keyed, sorted(map(str, read - keyed))


def test_prepared_folders_of_removed_recordings_are_removed(tmp_path):
    """Issue 52 defect 10: after adding a recording and removing two, only the prepared folder of the
    recordings there are now is left (the others name recordings that no longer exist: no run can read
    them); a folder of other options over existing recordings stays, and so does a folder that is not the
    cache's own (a user's, named like one), a link to a folder, or one without jaxpose's project.json."""
    root = _project(tmp_path / "project", 3, (30, 30, 30))
    names = sorted(p.name for p in root.iterdir() if p.is_dir())
    spare = tmp_path / "spare"
    shutil.move(root / names[2], spare)  # the third recording, added later
    config = RigProjectConfig(root=root, frame_offsets=("cam03=3",))
    load_rig_project(config, progress=False)
    load_rig_project(dataclasses.replace(config, recordings=(names[0],)), progress=False)  # another subset: kept while its recording is there
    cache_folder = root / ".jaxpose_cache"
    users = cache_folder / "prepared-notes"
    users.mkdir()
    (users / "project.json").write_text('{"mine": 1}')
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "project.json").write_text('{"layout": "coco17"}')
    (cache_folder / ("prepared-" + "0" * 32)).symlink_to(elsewhere)
    shutil.move(spare, root / names[2])
    load_rig_project(config, progress=False)
    assert len(_prepared_folders(root)) == 3 + 2  # the two subsets and all three, the user's folder and the link
    shutil.rmtree(root / names[0])
    shutil.rmtree(root / names[1])
    load_rig_project(config, progress=False)
    ours = [name for name in _prepared_folders(root) if name not in ("prepared-notes", "prepared-" + "0" * 32)]
    assert len(ours) == 1, ours
    assert (users / "project.json").read_text() == '{"mine": 1}' and (elsewhere / "project.json").exists()
    assert (cache_folder / ("prepared-" + "0" * 32)).is_symlink()


def test_a_project_json_written_before_its_type_is_read_as_it_was(small, tmp_path):
    """`cache.ProjectMeta` reads a prepared folder's project.json as jaxpose wrote it before the type (the
    rigs as plain nested lists): the same recordings, rigs and samples, read from the cache."""
    import json

    root = tmp_path / "project"
    shutil.copytree(small, root, ignore=shutil.ignore_patterns(".jaxpose_cache"))
    config = RigProjectConfig(root=root, frame_offsets=("cam03=3",))
    cold = load_rig_project(config, progress=False)
    (folder,) = _prepared_folders(root)
    written = root / ".jaxpose_cache" / folder / "project.json"
    meta = json.loads(written.read_text())
    assert meta["rigs"]["K"]["dtype"] == "<f4"
    meta["rigs"] = {field: value["ndarray"] for field, value in meta["rigs"].items()}
    written.write_text(json.dumps(meta, indent=1))
    warm = load_rig_project(config, progress=False)
    assert warm.prepared.startswith("read from the cache") and warm.recordings == cold.recordings
    assert isinstance(warm.recordings[0].cameras, tuple) and warm.camera_names == cold.camera_names
    jax.tree.map(np.testing.assert_array_equal, cold.validation.rigs, warm.validation.rigs)
    assert warm.validation.rigs.K.dtype == np.float32
    jax.tree.map(np.testing.assert_array_equal, cold.validation.samples, warm.validation.samples)
