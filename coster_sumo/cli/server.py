"""``coster-sumo serve``: a process that keeps the heavy imports loaded and runs each command in a fork.

A command of ``coster-sumo`` pays about 3 s of imports before it does any work (torch, SciPy,
scikit-learn, matplotlib, libsumo; bench/RESULTS.md, "The demo ... what 3 s would take"). While a
server runs, the ``coster-sumo`` command (:mod:`coster_sumo.cli.client`) hands its command line, its
folder, its environment and its terminal (standard input, output and error, as open file
descriptors) to the server over a Unix socket; the server forks, and the child runs the command as
the command line would, with everything already imported, writing straight to the user's terminal.
Its exit code goes back to the client, which exits with it; Ctrl-C in the client reaches the child.

Safety and staleness:

* the socket lives in a folder only this user can enter (mode 0700, owned by the user), so only the
  user's own processes can hand the server work; the server runs as the user;
* before every command the server checks that none of the files of the package it has loaded
  changed since it started; if one did it refuses (the client then runs the command itself) and
  exits, so an update of the package never runs old code;
* the server exits after :data:`IDLE_EXIT_S` without a command, and on ``coster-sumo serve --stop``.

libsumo holds one simulation per process: the server never starts one, each command does in its own
fork. torch's thread pools do not survive a fork: the server imports torch but never runs it.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from coster_sumo.infra import procs

IDLE_EXIT_S = 1800.0  # [s] the server exits after this long without a command
MAX_HEADER = 1 << 20  # [bytes] a command's header (argv, folder, environment)
Runner = Callable[[list[str]], int]  # runs one command line, returns its exit code
SOCKET_ENV = "COSTER_SUMO_SOCKET"  # a socket path of the user's choosing (tests, several servers)


def socket_path() -> Path:
    """Where the server listens: ``$COSTER_SUMO_SOCKET``, else a per-user folder in the runtime folder."""
    if os.environ.get(SOCKET_ENV):
        return Path(os.environ[SOCKET_ENV])
    base = os.environ.get("XDG_RUNTIME_DIR") or "/tmp"
    return Path(base) / f"coster-sumo-{os.getuid()}" / "server.sock"


def private_folder(path: Path) -> None:
    """Make (or check) the socket's folder: this user's own, entered by nobody else."""
    folder = path.parent
    folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    st = folder.stat()
    if st.st_uid != os.getuid() or st.st_mode & 0o077:
        mode = oct(st.st_mode & 0o777)
        raise OSError(f"{folder}: not a private folder of this user (owner {st.st_uid}, mode {mode})")


def send_message(conn: socket.socket, message: dict[str, Any], fds: list[int] | None = None) -> None:
    """One JSON message (length-prefixed), with file descriptors where given."""
    data = json.dumps(message).encode()
    frame = len(data).to_bytes(4, "big") + data
    if fds:
        socket.send_fds(conn, [frame], fds)
    else:
        conn.sendall(frame)


def _recv_exact(conn: socket.socket, n: int) -> bytes:
    out = b""
    while len(out) < n:
        chunk = conn.recv(n - len(out))
        if not chunk:
            raise EOFError("connection closed")
        out += chunk
    return out


def recv_message(conn: socket.socket, with_fds: int = 0) -> tuple[dict[str, Any], list[int]]:
    """The next message (and up to ``with_fds`` file descriptors sent with its first bytes)."""
    fds: list[int] = []
    if with_fds:
        head, fds, _, _ = socket.recv_fds(conn, 4, with_fds)
        if not head:
            raise EOFError("connection closed")
        head += _recv_exact(conn, 4 - len(head))
    else:
        head = _recv_exact(conn, 4)
    n = int.from_bytes(head, "big")
    if n > MAX_HEADER:
        raise ValueError(f"message of {n} bytes")
    return json.loads(_recv_exact(conn, n)), fds


# ----------------------------------------------------------------------------- the server


def _loaded_files() -> dict[str, int]:
    """Every loaded module file of the package (and its converters), with its modification time [ns]."""
    out: dict[str, int] = {}
    for name, module in list(sys.modules.items()):
        path = getattr(module, "__file__", None)
        if path and name.split(".")[0] == "coster_sumo":
            with contextlib.suppress(OSError):
                out[path] = os.stat(path).st_mtime_ns
    return out


def _changed(files: dict[str, int]) -> str | None:
    for path, mtime in files.items():
        try:
            if os.stat(path).st_mtime_ns != mtime:
                return path
        except OSError:
            return path
    return None


def preload() -> None:
    """Import what commands need, once: the simulation, the models and generation, the renders."""
    import coster_sumo.batch.task_imports  # noqa: F401 - libsumo, torch, scikit-learn, generation
    import coster_sumo.pipeline.viz  # noqa: F401 - matplotlib
    from coster_sumo.pipeline.viz import plt

    fig = plt.figure(figsize=(2, 2))  # matplotlib's first drawing loads fonts and caches: once, here
    fig.add_subplot().plot([0, 1], [0, 1], label="x")
    fig.legend()
    fig.savefig(io.BytesIO(), format="png")
    plt.close(fig)


def _run_command(run: Runner, listener: socket.socket, conn: socket.socket, header: dict[str, Any],
                 fds: list[int]) -> None:
    """In the forked child: become the command (its folder, environment, terminal) and run it."""
    procs.mark_imports_only()
    listener.close()
    runner = os.getpid()
    send_message(conn, {"pid": runner})
    signal.signal(signal.SIGCHLD, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    for target, fd in zip((0, 1, 2), fds, strict=False):
        os.dup2(fd, target)
        os.close(fd)
    sys.stdin = os.fdopen(0, "r", closefd=False)
    sys.stdout = os.fdopen(1, "w", buffering=1 if os.isatty(1) else -1, closefd=False)
    sys.stderr = os.fdopen(2, "w", buffering=1, closefd=False)
    os.chdir(header["cwd"])
    os.environ.clear()
    os.environ.update(header["env"])
    sys.argv = ["coster-sumo", *header["argv"]]

    finished = threading.Event()

    def client_gone() -> None:  # the client was killed before the command finished: stop as on Ctrl-C
        with contextlib.suppress(OSError):
            while conn.recv(1):
                pass
        if not finished.is_set():
            os.kill(runner, signal.SIGINT)

    threading.Thread(target=client_gone, daemon=True).start()
    rc = 1
    try:
        rc = run(header["argv"])
    except SystemExit as exc:  # argparse's --help and usage errors
        rc = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    except KeyboardInterrupt:
        rc = 130
    finally:
        # whatever happens here, this process ends here: it must never unwind into the server's loop
        try:
            finished.set()
            sys.stdout.flush()
            sys.stderr.flush()
            if os.getpid() == runner:  # not a process the command forked that ended by unwinding its stack
                send_message(conn, {"rc": rc})
        except BaseException:  # noqa: BLE001 - a closed terminal or a late signal changes nothing now
            pass
        os._exit(rc)


def serve(run: Runner, path: Path | None = None, idle_exit_s: float = IDLE_EXIT_S, quiet: bool = False) -> int:
    """Listen on ``path`` until :data:`IDLE_EXIT_S` without a command, a stop, or a package update;
    ``run(argv) -> exit code`` runs one command line (the command line's own entry, which the
    ``serve`` command hands in: it was imported, with every command, before the server started)."""
    path = path or socket_path()
    private_folder(path)
    if path.exists():
        if _alive(path):
            print(f"coster-sumo: error: a server already listens on {path}", file=sys.stderr)
            return 2
        path.unlink()
    preload()
    files = _loaded_files()
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(str(path))
    os.chmod(path, 0o600)
    listener.listen(16)
    listener.settimeout(1.0)
    if not quiet:
        print(f"coster-sumo server: listening on {path} (stop with `coster-sumo serve --stop`)", file=sys.stderr)
    last = time.monotonic()
    stopping = False
    try:
        while not stopping:
            with contextlib.suppress(ChildProcessError):
                while os.waitpid(-1, os.WNOHANG)[0]:
                    pass
            try:
                conn, _ = listener.accept()
            except TimeoutError:
                if time.monotonic() - last > idle_exit_s:
                    break
                continue
            last = time.monotonic()
            stopping = _handle(run, listener, conn, files, quiet)
    finally:
        listener.close()
        with contextlib.suppress(OSError):
            path.unlink()
    return 0


def _handle(run: Runner, listener: socket.socket, conn: socket.socket, files: dict[str, int],
            quiet: bool = True) -> bool:
    """One connection; True: the server should stop."""
    with conn:
        conn.settimeout(5.0)
        try:
            header, fds = recv_message(conn, with_fds=3)
        except (OSError, EOFError, ValueError):
            return False
        if header.get("op") == "stop":
            send_message(conn, {"stopped": True})
            return True
        if header.get("op") == "ping":
            send_message(conn, {"pid": os.getpid()})
            return False
        changed = _changed(files)
        if changed or len(fds) != 3:
            for fd in fds:
                os.close(fd)
            why = f"{changed} changed since the server started" if changed else "no terminal received"
            send_message(conn, {"refused": why})
            if not quiet:
                print(f"coster-sumo server: refused a command: {why}" + ("; exiting" if changed else ""),
                      file=sys.stderr, flush=True)
            return bool(changed)
        conn.settimeout(None)
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:
            _run_command(run, listener, conn, header, fds)  # never returns
        for fd in fds:
            os.close(fd)
        if not quiet:
            print(f"coster-sumo server: `{' '.join(header['argv'])}` in {header['cwd']} runs as process {pid}",
                  file=sys.stderr, flush=True)
    return False


def _ask(path: Path, op: str, timeout_s: float) -> bool:
    """Send ``op`` (ping, stop) to the server on ``path``; whether it answered."""
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
            s.settimeout(timeout_s)
            s.connect(str(path))
            send_message(s, {"op": op})
            recv_message(s)
            return True
    except (OSError, EOFError, ValueError):
        return False


def _alive(path: Path) -> bool:
    """Whether a server answers on ``path``."""
    return _ask(path, "ping", 2.0)


def stop(path: Path | None = None) -> bool:
    """Ask the server on ``path`` to exit; False if none answered."""
    return _ask(path or socket_path(), "stop", 5.0)


@contextlib.contextmanager
def serving(path: Path) -> Iterator[dict[str, str]]:
    """A ``coster-sumo serve`` on ``path`` in a child process while the block runs (benches); yields
    the environment whose ``coster-sumo`` commands reach it."""
    env = {**os.environ, SOCKET_ENV: str(path)}
    env.pop("COSTER_SUMO_SERVER", None)
    proc = subprocess.Popen([sys.executable, "-m", "coster_sumo.cli.client", "--quiet", "serve"], env=env)
    try:
        while not _alive(path):
            if proc.poll() is not None:
                raise OSError(f"{path}: coster-sumo serve did not start (exit code {proc.returncode})")
            time.sleep(0.2)
        yield env
    finally:
        stop(path)
        proc.wait(timeout=60)
