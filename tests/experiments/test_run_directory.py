"""One run per run directory (jaxpose.training.run_directory.exclusive)."""

import subprocess
import sys

import pytest

from jaxpose.training.run_directory import LOCK_FILE, exclusive

HOLD = """
import sys, time, pathlib
from jaxpose.training.run_directory import exclusive
with exclusive(pathlib.Path(sys.argv[1])):
    print("held", flush=True)
    time.sleep(60)
"""


@pytest.mark.processes
def test_a_second_run_on_a_held_directory_stops_at_once_naming_the_first(tmp_path):
    run_dir = tmp_path / "run"
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(run_dir)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(SystemExit, match=rf"run is in use by another run \(process {holder.pid} on "):
            with exclusive(run_dir):
                pytest.fail("two runs held one directory")
    finally:
        holder.kill()
        holder.wait()
    with exclusive(run_dir):  # the kernel released the killed holder's lock
        assert (run_dir / LOCK_FILE).exists()
    assert not (run_dir / LOCK_FILE).exists()


def test_a_directory_made_only_for_the_lock_is_removed_and_an_existing_one_kept(tmp_path):
    with exclusive(tmp_path / "new" / "run"):
        pass
    assert not (tmp_path / "new").exists()
    (tmp_path / "old").mkdir()
    with exclusive(tmp_path / "old"):
        (tmp_path / "old" / "config.json").write_text("{}")
    assert sorted(p.name for p in (tmp_path / "old").iterdir()) == ["config.json"]


def test_an_unwritable_run_directory_is_one_sentence(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(SystemExit, match=r"--run.run-dir .*file/run: cannot be written"):
        with exclusive(blocker / "run"):
            pass


@pytest.mark.parametrize("study", ["ablation", "search"])
def test_a_study_refuses_a_run_folder_before_training(tmp_path, study):
    """Issue 52: the studies wrote comparison.md / search.md into whatever --run.run-dir named, a run folder
    too; a study's summary goes into a folder of its own, and a run folder is refused before anything trains."""
    import importlib
    import json

    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text(json.dumps({"jaxpose_run": 1}))
    before = sorted(path.name for path in run.iterdir())
    with pytest.raises(SystemExit, match=r"run: is a run folder, which holds only its run; give the study a folder of its own"):
        importlib.import_module(f"experiments.{study}").main(["--dataset", "synthetic", "--run.run-dir", str(run)])
    assert sorted(path.name for path in run.iterdir()) == before
