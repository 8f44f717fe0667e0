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
