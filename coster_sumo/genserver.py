"""A run's generation in a process of its own, started before the command line imports anything else.

Generation needs torch, the models' code and the weights: about 1.5-2.5 s of imports and loading
on the 2-core machine of ``bench/RESULTS.md``, which a run paid after its nominal pass, in series.
``coster-sumo run`` and ``demo`` start a :class:`GenerationServer` first thing
(:func:`start_early`, from :func:`coster_sumo.cli.main`): a forked process that imports and loads
all that on the other core while the command line builds its parser and simulates the nominal
pass. The run then hands it the nominal scene and gets the planned scenarios back
(:meth:`GenerationServer.plan_scenarios`, the same as :func:`coster_sumo.core.plan_scenarios`,
which it calls); every snapshot drawn comes back as soon as it is drawn, so the held copies of the
nominal pass advance meanwhile as before.

The run's own process then never loads torch: what it forks later (held copies, renders) starts
from a process without thread pools. The server is only started from a process that has loaded
neither torch nor scikit-learn (a forked child of one that ran them may hang in them); elsewhere
(tests, the Python API) the run generates in its own process.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import traceback
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any

from coster_sumo.errors import CosterError
from coster_sumo.procs import ChildFailed, die_with_parent, signal_name

COMMANDS = ("run", "demo")  # the command-line commands that generate with the models

_server: GenerationServer | None = None


class GenerationServer:
    """The client side: a forked server process and the connection to it."""

    def __init__(self, pid: int, conn: Connection) -> None:
        self.pid, self.conn = pid, conn

    @classmethod
    def start(cls) -> GenerationServer | None:
        """Fork the server (it starts importing at once); None where this process has loaded torch or
        scikit-learn already, or cannot fork."""
        if "torch" in sys.modules or "sklearn" in sys.modules or not hasattr(os, "fork"):
            return None
        from multiprocessing import Pipe

        mine, theirs = Pipe()
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:  # pragma: no cover - the server's side runs in the child
            mine.close()
            code = 0
            try:
                _serve(theirs)
            except BaseException:  # noqa: BLE001 - the client reports the stopped server
                code = 1
            os._exit(code)
        theirs.close()
        return cls(pid, mine)

    def plan_scenarios(self, scene: Any, target: int, seed: int, gen: Any, snapshots: int = 1,
                       on_snapshot: Callable[[Any], None] | None = None, threads: int | None = None) -> list[Any]:
        """:func:`coster_sumo.core.plan_scenarios` in the server (its drivable area built there from
        ``scene.road_map``, as a run builds it), on ``threads`` torch threads (None: torch's choice);
        ``on_snapshot`` is called here with each snapshot as it is drawn. Errors of ours come back
        and are raised here; a server that stopped is :class:`~coster_sumo.procs.ChildFailed`."""
        try:
            self.conn.send(("plan", (scene, target, seed, gen, snapshots, threads)))
            while True:
                try:
                    kind, value = self.conn.recv()
                except (EOFError, OSError):
                    raise
                except Exception as exc:  # an answer that does not unpickle here
                    raise ChildFailed(f"generation failed: {type(exc).__name__}: {exc}") from None
                if kind == "snapshot":
                    if on_snapshot is not None:
                        on_snapshot(value)
                elif kind == "done":
                    return value  # type: ignore[no-any-return]
                elif kind == "error":
                    raise value
                else:
                    raise ChildFailed(f"generation failed: {value}")
        except (EOFError, OSError, BrokenPipeError):
            raise ChildFailed(f"the generation process stopped ({self._stopped()})") from None

    def _stopped(self) -> str:
        with contextlib.suppress(ChildProcessError):
            pid, status = os.waitpid(self.pid, 0)
            if pid and os.WIFSIGNALED(status):
                return f"crashed, {signal_name(os.WTERMSIG(status))}"
            if pid:
                return f"exit code {os.WEXITSTATUS(status)}"
        return "gone"

    def stop(self) -> None:
        """End the server (it holds nothing worth keeping; the run's children may still hold its
        connection open, so it is stopped, not waited for to see the connection close)."""
        with contextlib.suppress(OSError):
            self.conn.close()
        with contextlib.suppress(OSError):
            os.kill(self.pid, signal.SIGKILL)
        with contextlib.suppress(ChildProcessError, OSError):
            os.waitpid(self.pid, 0)


def _serve(conn: Connection) -> None:
    """The server: import and load, then answer ``plan`` requests until the connection closes."""
    die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the command's to handle
    with contextlib.suppress(OSError):  # the command's terminal is not the server's
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 1)
        os.close(devnull)
    from coster_sumo import weights
    from coster_sumo.core import plan_scenarios
    from coster_sumo.drivable import DrivableArea
    from coster_sumo.prior.infer import load_prior
    from coster_sumo.procs import torch_threads
    from coster_sumo.rollout.checkpoint import load_model
    from coster_sumo.rollout.vocab import MotionVocab

    for name, loader in ((weights.PRIOR, load_prior), (weights.ROLLOUT, load_model), (weights.VOCAB, MotionVocab.load)):
        with contextlib.suppress(Exception):  # the shipped ones, the usual case; --models DIR loads on use
            path = weights.weights_path(name, required=False)
            if path.is_file():
                weights.load_cached(path, loader)
    while True:
        try:
            kind, payload = conn.recv()
        except (EOFError, OSError):
            return
        if kind != "plan":
            continue
        scene, target, seed, gen, snapshots, threads = payload
        try:
            drivable = DrivableArea.from_road_map(scene.road_map)
            with torch_threads(threads):
                planned = plan_scenarios(scene, target, seed, gen, drivable, snapshots,
                                         on_snapshot=lambda snap: conn.send(("snapshot", snap)))
            conn.send(("done", planned))
        except CosterError as exc:
            conn.send(("error", exc))
        except Exception:  # noqa: BLE001 - sent back whole; the run raises it as one line
            conn.send(("failed", traceback.format_exc().strip().splitlines()[-1]))


def start_early(argv: list[str]) -> None:
    """From the command line, before it imports the commands: start the server when ``argv`` runs a
    command of :data:`COMMANDS` (not for ``--help``)."""
    global _server
    words = [a for a in argv if not a.startswith("-")]
    if _server is None and words and words[0] in COMMANDS and not {"-h", "--help"} & set(argv):
        # what both processes need (numpy, scipy, shapely) is imported once, before the fork
        import coster_sumo.core  # noqa: F401

        _server = GenerationServer.start()


def current() -> GenerationServer | None:
    """The server this process (or the process it was forked from) started, if any."""
    return _server


def stop() -> None:
    """Stop the server started here, if any."""
    global _server
    if _server is not None:
        _server.stop()
        _server = None
