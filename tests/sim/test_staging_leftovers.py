"""A process killed by a signal leaves its temporary folder of SUMO's outputs; the next one removes
it, and never the folder of a process that still runs (issue 59)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

from coster_sumo.sim import sumo_outputs

MAKE = ("import os, signal, sys\n"
        "from coster_sumo.sim.sumo_outputs import staging_folder\n"
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


def test_a_crashed_process_s_folder_goes_and_a_live_one_s_stays(tmp_path, monkeypatch):
    crashed, dead_folder = _start(tmp_path, "crash")
    assert crashed.wait(timeout=120) == -signal.SIGSEGV
    live, live_folder = _start(tmp_path, "live")
    try:
        assert dead_folder.is_dir() and live_folder.is_dir()  # atexit never ran for the crashed one
        assert dead_folder.name.startswith(sumo_outputs.STAGING_PREFIX)
        monkeypatch.setattr(sumo_outputs, "LOCK_MIN_AGE_S", 0.0)
        assert sumo_outputs.remove_dead_staging(tmp_path) == [dead_folder]
        assert not dead_folder.exists() and live_folder.is_dir()
    finally:
        live.communicate("", timeout=60)  # ends normally: removes its own
    assert not live_folder.exists()


def test_a_young_lock_and_a_folder_without_one_are_left_alone(tmp_path):
    young = tmp_path / f"{sumo_outputs.STAGING_PREFIX}young"
    young.mkdir()
    (young / sumo_outputs.LOCK_NAME).write_text("")  # unlocked, but maybe not locked yet by its maker
    other = tmp_path / f"{sumo_outputs.STAGING_PREFIX}older-version"
    other.mkdir()
    assert sumo_outputs.remove_dead_staging(tmp_path) == []
    assert young.is_dir() and other.is_dir()
