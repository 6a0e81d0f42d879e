"""The ``coster-sumo`` command: hands the command to a running server (:mod:`coster_sumo.cli.server`), or runs it.

Without a server (the usual case) this is :func:`coster_sumo.cli.command_line.main`. With one listening
(``coster-sumo serve``), the command line, the current folder, the environment and the terminal
go to the server, which runs the command in a fork that has torch, SciPy, scikit-learn, matplotlib
and libsumo loaded already; this process waits, passes Ctrl-C on, and exits with the command's
exit code. Where the server does not answer, or refuses (the package changed since it started),
the command runs here as without a server. ``COSTER_SUMO_SERVER=off`` never asks one.

This module imports nothing heavy: the hand-over must cost less than the imports it saves.
"""

from __future__ import annotations

import os
import signal
import socket
import sys
from collections.abc import Sequence

from coster_sumo.cli.server import recv_message, send_message, socket_path

FORWARDED = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def via_server(argv: list[str]) -> int | None:
    """The command's exit code, run by the server; None: no server took it."""
    path = socket_path()
    if not path.exists():
        return None
    conn = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        conn.settimeout(2.0)
        conn.connect(str(path))
        send_message(conn, {"argv": argv, "cwd": os.getcwd(), "env": dict(os.environ)},
                     fds=[sys.stdin.fileno(), sys.stdout.fileno(), sys.stderr.fileno()])
        answer, _ = recv_message(conn)
    except (OSError, EOFError, ValueError):
        conn.close()
        return None
    if "pid" not in answer:  # refused: the package changed under the server (it exits), or no terminal
        conn.close()
        return None
    pid = int(answer["pid"])

    def forward(signum: int, _frame: object) -> None:
        try:
            os.kill(pid, signum)
        except ProcessLookupError:
            pass

    for sig in FORWARDED:
        signal.signal(sig, forward)
    conn.settimeout(None)
    try:
        done, _ = recv_message(conn)
    except (OSError, EOFError, ValueError):
        print("coster-sumo: error: the server's process for this command ended without an exit code",
              file=sys.stderr)
        return 1
    finally:
        conn.close()
    return int(done.get("rc", 1))


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if os.environ.get("COSTER_SUMO_SERVER", "").lower() != "off" and "serve" not in args:
        rc = via_server(args)
        if rc is not None:
            return rc
    from coster_sumo.cli.command_line import main as cli_main

    return cli_main(args)


if __name__ == "__main__":
    sys.exit(main())
