"""Fault harness: commands killed at chosen moments, a full disk, a read-only folder, two commands on one output.

Each case counts what a user would lose or be misled by: files lost from an earlier output,
processes left running, hidden folders left beside or inside the output, rows missing or
duplicated in a batch. Every count must be 0. Commands run as the user runs them (``python -m
coster_sumo`` in a process of its own, in a new session so that what it leaves running can be found
by its process group).
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from coster_sumo.batch.store import ResultRow
from coster_sumo.cli.command_line import main

REPO = Path(__file__).resolve().parents[2]
CFG = REPO / "networks" / "intersection" / "intersection.sumocfg"
RUN = ["run", str(CFG), "--init", "random", "--rollout", "cvae", "--samples", "200", "--variants", "3", "--end", "45"]
pytestmark = [pytest.mark.slow, pytest.mark.sumo]


def _as_from_a_terminal() -> None:
    """Ctrl-C's default action in the child, as a shell gives it: a signal the test runner itself
    ignores would stay ignored in its children (Python then installs no KeyboardInterrupt)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _start(args: list[str], cwd: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.Popen([sys.executable, "-m", "coster_sumo", "-q", *args], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=_as_from_a_terminal)


def _group(pgid: int) -> list[int]:
    """Processes still alive in a process group (zombies excluded)."""
    alive = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[1].split()
        if int(fields[2]) == pgid and fields[0] != "Z":
            alive.append(int(d.name))
    return alive


def _left_running(pgid: int, wait_s: float = 5.0) -> list[int]:
    deadline = time.monotonic() + wait_s
    while (alive := _group(pgid)) and time.monotonic() < deadline:
        time.sleep(0.1)
    return alive


def _tree(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def _hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> tuple[Path, float]:
    """A finished run output, and how long the run took on this machine (the cases interrupt one like it)."""
    folder = tmp_path_factory.mktemp("finished")
    t0 = time.monotonic()
    proc = _start([*RUN, "-o", str(folder / "o")], folder)
    proc.communicate(timeout=600)
    assert proc.returncode == 0
    return folder / "o", time.monotonic() - t0


@pytest.mark.parametrize(("how", "share"), [("SIGKILL", 0.2), ("SIGKILL", 0.6), ("SIGKILL", 0.9),
                                            ("SIGINT", 0.2), ("SIGINT", 0.6), ("SIGINT", 0.9), ("SIGTERM", 0.5)])
def test_run_stopped_at_any_moment_loses_nothing_and_leaves_nothing(tmp_path, finished, how, share):
    from coster_sumo.infra.outdir import OutputLock, clean_leftovers

    earlier, seconds = finished
    out = tmp_path / "o"
    shutil.copytree(earlier, out)
    before = _tree(out)
    proc = _start([*RUN, "--seed", "1", "--overwrite", "-o", str(out)], tmp_path)
    time.sleep(share * seconds)
    if how == "SIGINT":  # Ctrl-C: the terminal signals the whole foreground group
        os.killpg(proc.pid, signal.SIGINT)
    else:  # kill PID / kill -9 PID: the command alone
        os.kill(proc.pid, getattr(signal, how))
    proc.communicate(timeout=120)
    assert _left_running(proc.pid) == [], f"{how} at {share:.0%}: processes left running"
    with OutputLock(out, wait_s=10.0):  # what the next command on this output does first
        clean_leftovers(out)
    after = _tree(out)
    finished_new = json.loads(after["summary.json"])["seed"] == 1
    assert finished_new or after == before, f"{how} at {share:.0%}: the earlier output changed"
    assert _hidden(tmp_path) == [], f"{how} at {share:.0%}: left {_hidden(tmp_path)}"


def test_two_runs_on_one_output_one_writes_the_other_says_so(tmp_path):
    out = tmp_path / "o"
    a = _start([*RUN, "-o", str(out)], tmp_path)
    time.sleep(1.5)
    b = _start([*RUN, "-o", str(out)], tmp_path)
    _, b_err = b.communicate(timeout=600)
    a.communicate(timeout=600)
    assert a.returncode == 0
    assert b.returncode == 2 and len(b_err.strip().splitlines()) == 1
    assert "another coster-sumo command is writing it" in b_err
    assert json.loads((out / "summary.json").read_text())["num_variants"] >= 1
    assert _hidden(tmp_path) == []


@pytest.mark.parametrize("share", [0.3, 0.6, 0.9])
def test_regress_killed_resumes_with_no_row_lost_or_twice(tmp_path, share):
    out = tmp_path / "r"
    args = ["regress", str(CFG), "--end", "45", "--init", "random", "--rollout", "cvae", "--samples", "100",
            "--variants", "2", "--planner", "replay", "--planner", "sumo", "--workers", "2", "-o", str(out)]
    t0 = time.monotonic()
    whole = _start([*args[:-1], str(tmp_path / "timing")], tmp_path)
    whole.communicate(timeout=900)
    seconds = time.monotonic() - t0
    proc = _start(args, tmp_path)
    time.sleep(share * seconds)
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=60)
    assert _left_running(proc.pid) == []
    rerun = _start(args, tmp_path)
    rerun.communicate(timeout=900)
    assert rerun.returncode == 0
    rows = [p.stem for p in (out / "results").glob("*.parquet")]
    expected = json.loads((tmp_path / "timing" / "summary.json").read_text())["runs"]["expected"]
    summary = json.loads((out / "summary.json").read_text())
    assert len(rows) == len(set(rows)) == summary["runs"]["recorded"] == expected
    assert not [p for p in out.rglob(".*") if p.name != ".lock" and p.name != ".coster-sumo.json"]


def test_convert_killed_before_its_rename_counts_no_scene_twice(tmp_path):
    """What a convert killed between writing a scene and renaming it leaves is no scene for a batch,
    and the next convert removes it."""
    from coster_sumo.batch.sources import parse_sources

    scenes = tmp_path / "scenes"
    shutil.copytree(CFG.parent, scenes / "a")
    (scenes / ".coster-sumo.json").write_text(json.dumps({"tool": "coster-sumo", "kind": "convert", "files": []}))
    shutil.copytree(CFG.parent, scenes / f".b.staging.{os.getpid() + 100000}.0a0b")
    assert len(parse_sources([str(scenes)])) == 1
    bogus = tmp_path / "not_a_scene.pkl"
    bogus.write_bytes(b"x")
    assert main(["-q", "convert", str(bogus), "-o", str(scenes)]) == 2
    assert _hidden(scenes) == [".coster-sumo.json"]


@pytest.mark.parametrize("where", ["coster_sumo.pipeline.outputs.write_json", "coster_sumo.infra.outdir.publish"])
def test_a_full_disk_is_one_line_and_leaves_no_half_output(tmp_path, capfd, monkeypatch, where):
    """ENOSPC injected where the run writes its summary, and where it renames its output into place."""
    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp_path / "o" / "summary.json"))

    monkeypatch.setattr(where, full)
    rc = main(["-q", *RUN, "-o", str(tmp_path / "o")])
    err = [ln for ln in capfd.readouterr().err.splitlines() if ln.strip()]
    assert rc == 1 and len(err) == 1 and "No space left on device" in err[0], err
    assert not (tmp_path / "o").exists() and _hidden(tmp_path) == []


def test_a_folder_it_may_not_write_is_one_line(tmp_path, capfd, monkeypatch):
    import coster_sumo.infra.outdir as outdir_module

    def read_only(out):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(out.parent))

    monkeypatch.setattr(outdir_module, "new_staging", read_only)
    rc = main(["-q", *RUN, "-o", str(tmp_path / "ro" / "o")])
    err = [ln for ln in capfd.readouterr().err.splitlines() if ln.strip()]
    assert rc == 1 and len(err) == 1 and "Permission denied" in err[0], err


def test_a_timed_out_run_is_retried_by_a_plain_rerun_a_crash_is_kept(tmp_path):
    out = tmp_path / "r"
    env_once = {"COSTER_TEST_ONCE": str(tmp_path / "once")}
    args = ["regress", str(CFG), "--end", "40", "--init", "random", "--rollout", "cv", "--variants", "1",
            "--planner", "tests.misbehaving_planners:HangOnce", "--planner", "tests.misbehaving_planners:Abort",
            "--timeout", "20", "-o", str(out)]
    for attempt in range(2):
        env = {**os.environ, "PYTHONPATH": str(REPO), **env_once}
        done = subprocess.run([sys.executable, "-m", "coster_sumo", "-q", *args], env=env, capture_output=True,
                              text=True, timeout=600)
        assert done.returncode == 1, done.stderr  # the Abort row fails both times
        rows = {r.planner.rsplit(":", 1)[1]: r for r in _rows(out)}
        assert len(rows) == 2
        if attempt == 0:
            assert "timed out" in str(rows["HangOnce"].reason)
            aborted_at = rows["Abort"].finished_at
        else:  # the timeout was the machine's: run again, and it finished; the crash is the input's: kept
            assert rows["HangOnce"].status == "ok"
            assert rows["Abort"].finished_at == aborted_at and "SIGABRT" in str(rows["Abort"].reason)


def _rows(out: Path) -> list[ResultRow]:
    from coster_sumo.batch.store import ResultStore

    return ResultStore(out / "results").read()


@pytest.mark.parametrize("how", ["SIGINT", "SIGKILL"])
def test_a_hung_variant_dies_with_run(tmp_path, finished, how):
    """A variant that hangs (no --timeout) is stopped with its run by Ctrl-C or kill -9: no holder,
    no worker left (before, both survived at about 120 MB each)."""
    _, seconds = finished
    out = tmp_path / "o"
    env_once = str(tmp_path / "once")
    env = {**os.environ, "PYTHONPATH": str(REPO), "COSTER_TEST_ONCE": env_once}
    proc = subprocess.Popen([sys.executable, "-m", "coster_sumo", "-q", *RUN, "--planner",
                             "tests.misbehaving_planners:HangOnce", "-o", str(out)], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=_as_from_a_terminal)
    deadline = time.monotonic() + 10 * seconds
    while not Path(env_once).exists() and time.monotonic() < deadline:  # a variant has started to hang
        time.sleep(0.2)
    assert Path(env_once).exists() and proc.poll() is None
    time.sleep(1.0)
    if how == "SIGINT":
        os.killpg(proc.pid, signal.SIGINT)
    else:
        os.kill(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=60)
    assert _left_running(proc.pid) == []
    assert not out.exists()
    if how == "SIGINT":  # Ctrl-C cleans up itself; after kill -9 the next command on OUT does (tested above)
        assert _hidden(tmp_path) == []
