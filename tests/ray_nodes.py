"""A real multi-node Ray cluster on this machine, for the Ray tests and bench/bench_ray_scaling.py.

Each node is a separate ``ray start`` process, as a user starts a cluster: a head that offers no
CPU (it schedules and runs no task) and worker nodes, each started in a working folder of its own.
Worker nodes must not see the driver's folders (OUT, the configurations it reads), so that a batch
that passes here needs no disk shared with the driver. Two ways, the stronger one first:

* ``mount namespace``: each worker node is started inside ``unshare --user --map-root-user --mount``
  with an empty tmpfs mounted over every hidden folder. Nothing on the node (Python, SUMO's C++,
  a shell) can see what the driver has there. Needs unprivileged user namespaces (Linux; some
  distributions switch them off).
* ``audit hook``: otherwise, a ``sitecustomize`` on the worker nodes' ``PYTHONPATH`` adds a Python
  audit hook that refuses every ``open`` below a hidden folder. It covers Python's reads and writes
  only, not a C++ library's.

:func:`unseen_by_workers` checks, with a task pinned to every worker node, that the node cannot read
a file the driver wrote into a hidden folder: the isolation is tested, not assumed.

The cluster is stopped by killing the processes whose command line names its own temporary folder
or port (``ray stop`` would stop every Ray instance of the user on the machine).
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
OBJECT_STORE_BYTES = 200 * 1024 * 1024  # per node; the tasks' files and results are small

_AUDIT_HOOK = '''\
import os, sys

_HIDDEN = [h for h in os.environ.get("COSTER_TEST_HIDDEN", "").split(os.pathsep) if h]


def _refuse_hidden(event, args):
    if event != "open" or not args or not isinstance(args[0], (str, bytes, os.PathLike)):
        return
    path = os.path.abspath(os.fsdecode(args[0]))
    for h in _HIDDEN:
        if path == h or path.startswith(h + os.sep):
            raise PermissionError(f"{path}: the driver's folder is not on this Ray node")


if _HIDDEN:
    sys.addaudithook(_refuse_hidden)
'''


@dataclass
class Cluster:
    address: str  # HOST:PORT of the head, for --address
    env: dict[str, str]  # the environment a driver process runs with
    temp_dir: Path
    isolation: str  # "mount namespace" | "audit hook"
    worker_cpus: tuple[int, ...]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def namespaces_work() -> bool:
    """Whether this user may create a user + mount namespace and mount a tmpfs in it."""
    if shutil.which("unshare") is None:
        return False
    try:
        done = subprocess.run(["unshare", "--user", "--map-root-user", "--mount", "sh", "-c",
                               "mount -t tmpfs -o size=1m tmpfs /mnt"], capture_output=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        return False
    return done.returncode == 0


def _kill_cluster(base: Path, temp_dir: Path, port: int) -> None:
    """Kill the cluster's processes: those started in a node's folder under ``base`` (Ray renames some,
    ``ray::DashboardAgent``, so their command line no longer says whose they are) and those whose command
    line names the cluster's temporary folder or port. A few rounds: a raylet may start a worker meanwhile."""
    marks = (str(temp_dir), f"127.0.0.1:{port}")
    for _ in range(5):
        killed = 0
        for pid_dir in Path("/proc").iterdir():
            if not pid_dir.name.isdigit() or int(pid_dir.name) == os.getpid():
                continue
            try:
                cwd = Path(os.readlink(pid_dir / "cwd"))
                cmdline = (pid_dir / "cmdline").read_bytes().decode(errors="replace")
            except OSError:
                continue
            if cwd.is_relative_to(base) or any(m in cmdline for m in marks):
                try:
                    os.kill(int(pid_dir.name), signal.SIGKILL)
                    killed += 1
                except OSError:
                    pass
        if not killed:
            return
        time.sleep(0.5)


@contextmanager
def ray_cluster(base: Path, worker_cpus: Sequence[int], hidden: Sequence[Path],
                isolation: str | None = None) -> Iterator[Cluster]:
    """A head (no CPU) and one worker node per entry of ``worker_cpus`` (its CPU count), each in its
    own folder under ``base``; the worker nodes do not see ``hidden`` (module docstring).
    ``isolation``: "mount namespace" or "audit hook" (default: the first that works here)."""
    ray_bin = Path(sys.executable).parent / "ray"
    if isolation is None:
        isolation = "mount namespace" if namespaces_work() else "audit hook"
    base = Path(os.path.abspath(base))
    hidden = [Path(os.path.abspath(h)) for h in hidden]
    for h in hidden:
        h.mkdir(parents=True, exist_ok=True)
    temp_dir = Path(f"/tmp/ray-{uuid.uuid4().hex[:8]}")  # short: Ray's socket paths must fit 108 bytes
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "RAY_AUTH_MODE": "disabled",
           "PYTHONPATH": os.pathsep.join(dict.fromkeys([str(REPO), *filter(None, os.environ.get("PYTHONPATH",
                                                                                               "").split(os.pathsep))]))}
    env.pop("RAY_ADDRESS", None)
    node_env = dict(env)
    if isolation == "audit hook":
        hook_dir = base / "audit_hook"
        hook_dir.mkdir(parents=True, exist_ok=True)
        (hook_dir / "sitecustomize.py").write_text(_AUDIT_HOOK)
        node_env["PYTHONPATH"] = os.pathsep.join([str(hook_dir), env["PYTHONPATH"]])
        node_env["COSTER_TEST_HIDDEN"] = os.pathsep.join(str(h) for h in hidden)
    port = _free_port()
    address = f"127.0.0.1:{port}"
    common = ["--node-ip-address=127.0.0.1", f"--temp-dir={temp_dir}", "--disable-usage-stats",
              f"--object-store-memory={OBJECT_STORE_BYTES}"]
    starts = [([str(ray_bin), "start", "--head", f"--port={port}", "--num-cpus=0", "--include-dashboard=false",
                *common], env)]
    for cpus in worker_cpus:
        cmd = [str(ray_bin), "start", f"--address={address}", f"--num-cpus={cpus}", *common]
        if isolation == "mount namespace":
            mounts = " && ".join(f"mount -t tmpfs -o size=1m tmpfs {shlex.quote(str(h))}" for h in hidden)
            cmd = ["unshare", "--user", "--map-root-user", "--mount", "sh", "-c",
                   f'{mounts or "true"} && exec "$@"', "sh", *cmd]
        starts.append((cmd, node_env))
    try:
        for i, (cmd, cmd_env) in enumerate(starts):
            cwd = base / f"node{i}"
            cwd.mkdir(parents=True, exist_ok=True)
            done = subprocess.run(cmd, cwd=cwd, env=cmd_env, capture_output=True, text=True, timeout=180)
            if done.returncode != 0:
                raise RuntimeError(f"ray start failed ({' '.join(cmd[:3])}...): {done.stderr[-2000:]}")
        cluster = Cluster(address, env, temp_dir, isolation, tuple(worker_cpus))
        _wait_for_nodes(cluster, len(worker_cpus) + 1)
        yield cluster
    finally:
        _kill_cluster(base, temp_dir, port)
        shutil.rmtree(temp_dir, ignore_errors=True)


_DRIVER_PROBE = '''\
import json, sys, ray
from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

ray.init(address=sys.argv[1], include_dashboard=False, log_to_driver=False)
nodes = [n for n in ray.nodes() if n["Alive"]]
if sys.argv[2] == "count":
    print(json.dumps([n["Resources"].get("CPU", 0) for n in nodes]))
    sys.exit(0)


@ray.remote(num_cpus=1)
def read(path):
    import os
    try:
        with open(path) as fh:
            return {"node": ray.get_runtime_context().get_node_id(), "read": fh.read(), "cwd": os.getcwd()}
    except OSError as exc:
        return {"node": ray.get_runtime_context().get_node_id(), "error": type(exc).__name__, "cwd": os.getcwd()}


workers = [n["NodeID"] for n in nodes if n["Resources"].get("CPU", 0) > 0]
print(json.dumps(ray.get([read.options(scheduling_strategy=NodeAffinitySchedulingStrategy(w, soft=False))
                          .remote(sys.argv[2]) for w in workers])))
'''


def _probe(cluster: Cluster, arg: str) -> object:
    done = subprocess.run([sys.executable, "-c", _DRIVER_PROBE, cluster.address, arg], env=cluster.env,
                          capture_output=True, text=True, timeout=180)
    if done.returncode != 0:
        raise RuntimeError(f"probe failed: {done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _wait_for_nodes(cluster: Cluster, n: int, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        cpus = _probe(cluster, "count")
        assert isinstance(cpus, list)
        if len(cpus) >= n or time.monotonic() > deadline:
            break
        time.sleep(1.0)
    if len(cpus) < n:
        raise RuntimeError(f"only {len(cpus)} of {n} Ray nodes came up")


def unseen_by_workers(cluster: Cluster, sentinel: Path) -> list[dict[str, str]]:
    """What a task pinned to each worker node gets when it reads ``sentinel`` (a file the driver wrote
    into a hidden folder): ``{"node", "cwd", "error"}`` where it could not, ``"read"`` where it could."""
    found = _probe(cluster, str(Path(os.path.abspath(sentinel))))
    assert isinstance(found, list)
    return found


def node_cpus(cluster: Cluster) -> list[float]:
    """Every live node's CPU count (the head's is 0: no task runs there)."""
    cpus = _probe(cluster, "count")
    assert isinstance(cpus, list)
    return cpus
