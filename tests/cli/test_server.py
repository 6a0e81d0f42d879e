"""``coster-sumo serve``: commands handed to a server behave as run alone, and an update is never served stale."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from coster_sumo.cli import server

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from behaviour import outcomes_of_run  # noqa: E402

CLIENT = [sys.executable, "-m", "coster_sumo.cli.client"]
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def served(tmp_path: Path):  # noqa: ANN201
    """A server on a socket of this test's own; yields (environment for clients, the server's process)."""
    folder = tmp_path / "sock"
    env = {**os.environ, server.SOCKET_ENV: str(folder / "s.sock")}
    env.pop("COSTER_SUMO_SERVER", None)
    proc = subprocess.Popen([*CLIENT, "serve"], env=env, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not server._alive(folder / "s.sock"):
        assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
        assert time.monotonic() < deadline, "the server did not start"
        time.sleep(0.2)
    yield env, proc
    server.stop(folder / "s.sock")
    try:
        proc.wait(timeout=20)
    finally:
        proc.kill()


def _client(args: list[str], env: dict[str, str], cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*CLIENT, *args], env=env, cwd=cwd, capture_output=True, text=True, timeout=300)


def _server_lines(proc: subprocess.Popen[str], env: dict[str, str]) -> list[str]:
    server.stop(Path(env[server.SOCKET_ENV]))
    _, err = proc.communicate(timeout=20)
    return err.splitlines()


def test_the_demo_through_the_server_has_the_outcomes_it_has_alone(served, tmp_path: Path) -> None:
    env, proc = served
    alone = _client(["--quiet", "demo", "-o", "alone"], {**env, "COSTER_SUMO_SERVER": "off"}, tmp_path)
    via = _client(["--quiet", "demo", "-o", "served"], env, tmp_path)
    assert (alone.returncode, via.returncode) == (0, 0), via.stderr
    assert via.stdout.replace("served", "alone") == alone.stdout  # written to the client's own terminal
    assert outcomes_of_run(tmp_path / "served") == outcomes_of_run(tmp_path / "alone")
    lines = _server_lines(proc, env)
    assert any("demo -o served" in line and "runs as process" in line for line in lines)  # it did serve it
    assert not any("demo -o alone" in line for line in lines)


def test_a_bad_input_gets_the_same_line_and_exit_code(served, tmp_path: Path) -> None:
    env, proc = served
    missing = str(tmp_path / "nowhere.sumocfg")
    alone = _client(["run", missing, "-o", "out"], {**env, "COSTER_SUMO_SERVER": "off"}, tmp_path)
    via = _client(["run", missing, "-o", "out"], env, tmp_path)
    assert alone.returncode == 2 and "nowhere.sumocfg" in alone.stderr
    assert (via.returncode, via.stderr, via.stdout) == (alone.returncode, alone.stderr, alone.stdout)
    usage = _client(["run"], env, tmp_path)  # argparse's usage error (a SystemExit in the served process)
    assert usage.returncode == 2 and "usage:" in usage.stderr
    assert sum("runs as process" in line for line in _server_lines(proc, env)) == 2


def test_a_changed_package_is_never_served(served, tmp_path: Path) -> None:
    """A file the server loaded changes: the command runs alone (same result), and the server exits."""
    env, proc = served
    loaded = Path(server.__file__)
    before = loaded.stat()
    os.utime(loaded, ns=(before.st_atime_ns, before.st_mtime_ns + 1_000_000_000))
    try:
        done = _client(["run", str(tmp_path / "nowhere.sumocfg")], env, tmp_path)
    finally:
        os.utime(loaded, ns=(before.st_atime_ns, before.st_mtime_ns))
    assert done.returncode == 2 and "nowhere.sumocfg" in done.stderr
    assert proc.wait(timeout=30) == 0
    _, err = proc.communicate()
    assert "server.py changed since the server started; exiting" in err


def test_ctrl_c_in_the_client_stops_the_served_command(served, tmp_path: Path) -> None:
    env, proc = served
    client = subprocess.Popen([*CLIENT, "demo", "-o", "out"], env=env, cwd=tmp_path, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    time.sleep(1.5)
    client.send_signal(signal.SIGINT)
    _, err = client.communicate(timeout=60)
    assert client.returncode == 130 and "interrupted" in err
    assert not (tmp_path / "out" / "summary.json").exists()  # no half-written OUT
    runner = [int(line.rsplit(" ", 1)[1]) for line in _server_lines(proc, env) if "runs as process" in line]
    time.sleep(0.5)
    assert runner
    for pid in runner:  # the served process is gone, or a zombie nobody reaped yet: not running
        stat = Path(f"/proc/{pid}/stat")
        assert not stat.exists() or stat.read_text().rsplit(")", 1)[1].split()[0] in ("Z", "X")


def test_a_sumo_crash_in_a_served_run_is_one_line(tmp_path: Path) -> None:
    """The served run keeps the command line's crash isolation: SUMO aborting in the nominal pass
    stops the run with one line and leaves nothing, and the server goes on."""
    sock = tmp_path / "sock" / "s.sock"
    env = {**os.environ, server.SOCKET_ENV: str(sock)}
    env.pop("COSTER_SUMO_SERVER", None)
    code = ("import os, sys, coster_sumo.pipeline.run as r; r.nominal_pass = lambda *a, **k: os.abort(); "
            "from coster_sumo.cli.client import main; sys.exit(main(['serve']))")
    proc = subprocess.Popen([sys.executable, "-c", code], env=env, stderr=subprocess.PIPE, text=True)
    try:
        while not server._alive(sock):
            assert proc.poll() is None
            time.sleep(0.2)
        cfg = REPO / "networks" / "intersection" / "intersection.sumocfg"
        done = _client(["-q", "run", str(cfg), "--end", "20", "-o", "o"], env, tmp_path)
        err = [line for line in done.stderr.splitlines() if line.strip()]
        assert done.returncode == 1 and len(err) == 1, err
        assert f"run of {cfg}: stopped, crashed (SIGABRT)" in err[0]
        assert [p.name for p in tmp_path.iterdir()] == ["sock"]  # no OUT, no staging folder, no lock
        assert _client(["run", str(tmp_path / "nowhere.sumocfg")], env, tmp_path).returncode == 2  # still serving
    finally:
        server.stop(sock)
        proc.wait(timeout=30)


def test_the_socket_folder_must_be_private(tmp_path: Path) -> None:
    folder = tmp_path / "shared"
    folder.mkdir(mode=0o755)
    folder.chmod(0o755)
    done = subprocess.run([*CLIENT, "serve"], env={**os.environ, server.SOCKET_ENV: str(folder / "s.sock")},
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 1
    assert done.stderr.startswith("coster-sumo: error:") and "not a private folder" in done.stderr
