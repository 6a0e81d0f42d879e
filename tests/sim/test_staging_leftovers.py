"""A process killed by a signal leaves its temporary folder of SUMO's outputs; the next one removes
it, and never the folder of a process that still runs (issue 59)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

from coster_sumo.infra import staging

MAKE = ("import os, signal, sys\n"
        "from coster_sumo.infra.staging import staging_folder\n"
        "print(staging_folder(), flush=True)\n"
        "if sys.argv[1] == 'crash':\n"
        "    os.kill(os.getpid(), signal.SIGSEGV)\n"
        "sys.stdin.read()\n")


def _start(tmp: Path, how: str) -> tuple[subprocess.Popen[str], Path]:
    env = {**os.environ, "TMPDIR": str(tmp)}
    proc = subprocess.Popen([sys.executable, "-c", MAKE, how], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            text=True, env=env)
    assert proc.stdout is not None
    return proc, Path(proc.stdout.readline().strip())


def test_a_crashed_process_s_folder_goes_and_a_live_one_s_stays(tmp_path):
    crashed, dead_folder = _start(tmp_path, "crash")
    assert crashed.wait(timeout=120) == -signal.SIGSEGV
    assert dead_folder.is_dir()  # atexit never ran for the crashed one
    assert dead_folder.name.startswith(staging.STAGING_PREFIX)
    live, live_folder = _start(tmp_path, "live")  # the next process removes it as it makes its own
    try:
        assert not dead_folder.exists() and live_folder.is_dir()
        assert staging.remove_dead_staging(tmp_path) == []
        assert live_folder.is_dir()
    finally:
        live.communicate("", timeout=60)  # ends normally: removes its own
    assert not live_folder.exists()


def test_a_folder_without_a_lock_file_is_left_alone(tmp_path):
    being_made = tmp_path / f"{staging.STAGING_PREFIX}being-made"
    being_made.mkdir()
    (being_made / f"{staging.LOCK_NAME}.new").write_text("")  # its maker locks it, then renames it
    other = tmp_path / f"{staging.STAGING_PREFIX}older-version"
    other.mkdir()
    assert staging.remove_dead_staging(tmp_path) == []
    assert being_made.is_dir() and other.is_dir()


SUPERVISED = ("import os, signal\n"
              "from coster_sumo.infra.procs import ChildFailed, run_supervised\n"
              "from coster_sumo.infra.staging import staging_folder\n"
              "def work():\n"
              "    (staging_folder() / 'out.xml').write_text('x')\n"
              "    os.kill(os.getpid(), signal.SIGSEGV)\n"
              "try:\n"
              "    run_supervised(work, 'a run')\n"
              "except ChildFailed as exc:\n"
              "    print(exc)\n")


def test_a_supervised_command_whose_child_crashes_leaves_no_folder(tmp_path):
    proc = subprocess.run([sys.executable, "-c", SUPERVISED], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "TMPDIR": str(tmp_path)})
    assert "a run: stopped, crashed (SIGSEGV)" in proc.stdout, proc.stderr
    assert not list(tmp_path.glob(staging.STAGING_PREFIX + "*"))
