"""The demand of a standalone SUMO export: the copied route and additional files, made fit for
the FCD replay device (:mod:`coster_sumo.exports.sumo`).

Three rewrites of the copied files, each for one reason (measured on SUMO 1.28, ``docs/sumo.md §11``):

- **Insertion checks.** The device inserts a vehicle at its first entry like any other vehicle, and
  a refused insertion delays it and its whole trajectory (entries play in order). On the game
  scenarios of the SUMO wheel the adversary, staged at its first pose on a busy lane at speed 0,
  waited 2.3 s for a gap. The device's vehicles take the ``insertion-checks`` option, an element
  of a route file its own ``insertionChecks`` attribute; so the export sets the option to ``none``
  and writes the checks the pass used (the configuration's option, default ``all``) onto every
  ``<vehicle>``, ``<trip>`` and ``<flow>`` that does not name its own: the configuration's own
  traffic is inserted as in the pass, the replayed vehicles exactly when their file says.
- **Dropping the target.** SUMO refuses two vehicles with one id, so a target the FCD file drives
  leaves the demand: its ``<vehicle>``/``<trip>`` is removed from whichever copied file holds it
  (the game scenarios keep their routes in additional files).
- **Expanding flows.** A flow member cannot be removed (a flow makes ``<id>.0``, ``<id>.1``, ...
  and stops the run when one of those ids exists already). When the target is one, every
  top-level ``<flow>`` of the copied files is replaced by the vehicles it made in the pass: one
  plain ``sumo`` run of the export (no FCD device, the pass's options and seed) writes them with
  ``--vehroute-output`` (intended departure, route, type, the speed factor drawn); the target is
  left out. All flows, not only the target's: members of probability flows depart by one random
  stream shared by all flows, and routes and types from distributions are drawn from one stream
  at departure, so dropping one flow would re-draw the others. The expanded vehicles carry their
  route and speed factor, so nothing is drawn for them again.

  That plain run is the nominal pass again, as long as plain ``sumo`` itself (on a congested
  freeway 33 s of a 100 s ``run``). So the nominal pass of a configuration with flows writes the
  same vehroute output (:func:`pass_route_args`, :func:`remember_pass_routes`) and an export whose
  window ends before that pass ended takes its members from there (:func:`pass_routes`), leaving
  out those whose intended departure lies after the export's end. Members that were due within the
  window but not yet inserted at its end may be listed where the plain run lists none: they wait
  for a gap in the export as they did in the pass, and never enter the window either way. The
  ``arrival`` SUMO writes is left out of both: it tells where the pass that wrote it stopped, not
  what the export runs.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import gzip
import hashlib
import io
import os
import re
import subprocess
import tempfile
import time
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterator
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from defusedxml import ElementTree as SafeET

from coster_sumo.errors import InputError, SumoError
from coster_sumo.formats.sumocfg import config_files, open_maybe_gzip, parse_time, read_sumocfg
from coster_sumo.infra import sumo_install
from coster_sumo.sim.sumo_outputs import declares, sandbox

if TYPE_CHECKING:
    from coster_sumo.sim.session import SumoSession

DEMAND_TAGS = ("vehicle", "trip", "flow")
# what shows an expansion's progress (it is a plain sumo run of the whole window: as long as plain
# sumo itself): called with the simulated seconds done and the window's length; set around an
# export by whoever shows progress (``coster-sumo run``'s outputs phase); None: nothing shown
EXPANSION_PROGRESS: ContextVar[Callable[[float, float], object] | None] = ContextVar("expansion_progress",
                                                                                     default=None)
STEP_LOG = re.compile(rb"Step #(\d+(?:\.\d+)?)")
EXPANDED_FILE = "flows_expanded.rou.xml"
XSI = "http://www.w3.org/2001/XMLSchema-instance"


def _read(path: Path) -> tuple[ET.ElementTree, ET.Element]:
    """The parsed file and its root element."""
    with open_maybe_gzip(path) as fh:
        tree = SafeET.parse(fh, forbid_dtd=True)
    return tree, tree.getroot()


def _serialized(tree: ET.ElementTree) -> bytes:
    ET.register_namespace("xsi", XSI)
    buf = io.BytesIO()
    tree.write(buf, encoding="UTF-8", xml_declaration=True)
    return buf.getvalue()


def _write(data: bytes, path: Path) -> None:
    opener: Any = gzip.open if path.suffix == ".gz" else open
    with opener(path, "wb") as fh:
        fh.write(data)


# Every variant of a run exports a copy of the same demand files, rewritten alike: each distinct
# content is parsed (and rewritten) once per process, keyed by its bytes, so an edited file is read
# anew. On the wheel's fokr_bs_demo (2,325 trips) that parsing took 0.28 s of each variant's export.
_MEMO_ENTRIES = 16
_ids_memo: dict[bytes, dict[str, set[str]]] = {}
_rewrite_memo: dict[tuple[Any, ...], tuple[bytes | None, dict[str, list[str]]]] = {}


def _content_key(path: Path) -> bytes:
    return hashlib.sha1(path.read_bytes()).digest()


def _remember(memo: dict[Any, Any], key: Any, value: Any) -> None:
    if len(memo) >= _MEMO_ENTRIES:
        memo.clear()
    memo[key] = value


def demand_ids(path: Path) -> dict[str, set[str]]:
    """Ids of the top-level ``<vehicle>``/``<trip>`` (key ``"vehicle"``) and ``<flow>`` (``"flow"``)."""
    key = _content_key(path)
    if key not in _ids_memo:
        out: dict[str, set[str]] = {"vehicle": set(), "flow": set()}
        for el in _read(path)[1]:
            if el.tag in DEMAND_TAGS and el.get("id") is not None:
                out["flow" if el.tag == "flow" else "vehicle"].add(str(el.get("id")))
        _remember(_ids_memo, key, out)
    return copy.deepcopy(_ids_memo[key])


def rewrite_demand(path: Path, *, checks: str | None = None, drop_vehicles: frozenset[str] = frozenset(),
                   drop_flows: bool = False, end: float | None = None) -> dict[str, list[str]]:
    """Rewrite one copied route or additional file in place (see the module docstring).

    Args:
        path: the file (gzip kept gzip).
        checks: ``insertionChecks`` value for every ``<vehicle>``/``<trip>``/``<flow>`` without one
            (None: leave them).
        drop_vehicles: ids of top-level ``<vehicle>``/``<trip>`` elements to remove.
        drop_flows: remove every top-level ``<flow>``.
        end: [s] the export's end: a top-level ``<flow>`` that begins at or after it is removed.
            It inserts nothing before the end, and SUMO refuses to load it when it has no ``end``
            of its own (its end defaults to the run's, which then lies before its begin).

    Returns:
        ``{"vehicles": [...], "flows": [...], "flows_after_end": [...]}``: the ids removed. A file
        without changes is not written.
    """
    key = (_content_key(path), checks, drop_vehicles, drop_flows, end)
    if key not in _rewrite_memo:
        _remember(_rewrite_memo, key, _rewritten(path, checks, drop_vehicles, drop_flows, end))
    data, removed = _rewrite_memo[key]
    if data is not None:
        _write(data, path)
    return copy.deepcopy(removed)


def _rewritten(path: Path, checks: str | None, drop_vehicles: frozenset[str], drop_flows: bool, end: float | None
               ) -> tuple[bytes | None, dict[str, list[str]]]:
    """:func:`rewrite_demand` of ``path`` without writing it: the new file's bytes (None: no
    change) and the ids removed."""
    tree, root = _read(path)
    removed: dict[str, list[str]] = {"vehicles": [], "flows": [], "flows_after_end": []}
    changed = False
    for el in list(root):
        vid = el.get("id", "")
        if el.tag in ("vehicle", "trip") and vid in drop_vehicles:
            root.remove(el)
            removed["vehicles"].append(vid)
            changed = True
        elif el.tag == "flow" and drop_flows:
            root.remove(el)
            removed["flows"].append(vid)
            changed = True
        elif el.tag == "flow" and end is not None and _begin_s(el, path) >= end:
            root.remove(el)
            removed["flows_after_end"].append(vid)
            changed = True
    if checks is not None:
        for el in root.iter():
            if el.tag in DEMAND_TAGS and el.get("insertionChecks") is None:
                el.set("insertionChecks", checks)
                changed = True
    return (_serialized(tree) if changed else None), removed


def _begin_s(flow: ET.Element, path: Path) -> float:
    """A flow's ``begin`` [s] (SUMO's default: 0); unreadable counts as 0 (kept: SUMO will say)."""
    try:
        return parse_time(flow.get("begin") or "0", f"{path}: flow {flow.get('id')!r}")
    except InputError:
        return 0.0


def expand_flows(config: Path, flows: set[str], leave_out: frozenset[str], out: Path, *, checks: str,
                 timeout_s: float = 3600.0, same_without: frozenset[str] = frozenset(),
                 from_pass: PassRoutes | None = None) -> list[str]:
    """Write ``out``: every member of ``flows`` that the export's configuration runs, as a vehicle.

    Runs plain ``sumo -c config`` without the FCD replay device (a temporary vehroute file beside
    ``out``), keeps the vehicles whose id is ``<flow id>.<n>`` for a flow in ``flows``, drops those in
    ``leave_out``, gives each one ``insertionChecks=checks`` and the route it departed with (a
    rerouted vehicle's first route). Returns the ids written, in departure order.

    ``same_without``: names of the configuration's files the expansion does not depend on (the FCD
    replay device's, which it runs without); an expansion whose other inputs are the same as an
    earlier one's in this process is copied from it, not simulated again (a run's variants differ
    only there: on the wheel's ramp the expanded files of its variants were byte-identical).

    ``from_pass``: the nominal pass's vehroute output (:func:`pass_routes`); the members are taken
    from it, up to the pass's ``end``, instead of running SUMO (module docstring).
    """
    if from_pass is not None:
        return _write_members(SafeET.fromstring(from_pass.data, forbid_dtd=True), flows, leave_out, out,
                              checks=checks, end=from_pass.end)
    key = _expansion_key(config, flows, leave_out, checks, same_without)
    if key in _EXPANDED:
        data, kept = _EXPANDED[key]
        _write(data, out)
        return list(kept)
    ids = _expand(config, flows, leave_out, out, checks=checks, timeout_s=timeout_s)
    if len(_EXPANDED) >= MAX_EXPANSIONS_KEPT:
        _EXPANDED.pop(next(iter(_EXPANDED)))
    _EXPANDED[key] = (out.read_bytes(), tuple(ids))
    return ids


MAX_EXPANSIONS_KEPT = 8
_EXPANDED: dict[str, tuple[bytes, tuple[str, ...]]] = {}


def _expansion_key(config: Path, flows: set[str], leave_out: frozenset[str], checks: str,
                   same_without: frozenset[str]) -> str:
    """What an expansion depends on: the bytes of the files the configuration names (but
    ``same_without``), the flows kept and left out, the insertion checks."""
    h = hashlib.sha256(repr((sorted(flows), sorted(leave_out), checks)).encode())
    for f in config_files(config):
        if f.name not in same_without:
            h.update(f.name.encode() + b"\0" + (f.read_bytes() if f.is_file() else b"(missing)") + b"\0")
    return h.hexdigest()


def _expand(config: Path, flows: set[str], leave_out: frozenset[str], out: Path, *, checks: str,
            timeout_s: float) -> list[str]:
    """:func:`expand_flows` by running SUMO."""
    tmp = out.with_name(f".{out.name}.vehroute.xml")
    quiet = sandbox(config).config or config  # without the configuration's own outputs (none beside it)
    cmd = [sumo_install.binary("sumo"), "-c", str(quiet), "--device.fcd-replay.files", "",
           *pass_route_args(tmp), "--no-warnings", "true"]
    progress = EXPANSION_PROGRESS.get()
    try:
        if progress is None:
            proc = subprocess.run([*cmd, "--no-step-log", "true"], capture_output=True, text=True,
                                  env=sumo_install.subprocess_env(), timeout=timeout_s, cwd=config.parent)
        else:
            proc = _run_showing_steps(cmd, config, progress, timeout_s)
        if proc.returncode != 0 or not tmp.is_file():
            lines = (proc.stderr or proc.stdout).strip().splitlines()
            # sumo ends with "Quitting (on error)."; the line that says what went wrong comes before
            said = [ln for ln in lines if ln.startswith("Error:")] or lines[-1:] or ["no output"]
            raise SumoError(f"{config}: expanding its flows with sumo failed: {said[-1]}")
        root = _read(tmp)[1]
    finally:
        tmp.unlink(missing_ok=True)
    return _write_members(root, flows, leave_out, out, checks=checks, end=None)


def _write_members(root: ET.Element, flows: set[str], leave_out: frozenset[str], out: Path, *, checks: str,
                   end: float | None) -> list[str]:
    """``out`` from a vehroute output's ``root`` (:func:`expand_flows`); ``end`` [s]: members whose
    intended departure lies after it are left out (None: all)."""
    new = ET.Element("routes")
    new.append(ET.Comment(" coster-sumo export: the members of the configuration's flows as the pass ran "
                          "them (vehroute output of SUMO without the FCD replay device; intended departure, "
                          "first route, speed factor drawn) "))
    kept: list[str] = []
    for el in root:
        vid = el.get("id", "")
        if el.tag != "vehicle" or vid.rpartition(".")[0] not in flows or vid in leave_out:
            continue
        if end is not None and float(el.get("depart", "0")) > end + 1e-6:
            continue
        el.attrib.pop("arrival", None)  # where the writing pass stopped (module docstring)
        dist = el.find("routeDistribution")
        if dist is not None:  # rerouted on the way: it departed with the first route
            first = dist.find("route")
            el.remove(dist)
            if first is not None:
                el.insert(0, ET.Element("route", {"edges": first.get("edges", "")}))
        el.set("insertionChecks", checks)
        new.append(el)
        kept.append(vid)
    ET.indent(new)
    _write(_serialized(ET.ElementTree(new)), out)
    return kept


@dataclass(frozen=True)
class PassRoutes:
    """The vehroute output of a nominal pass (:func:`pass_route_args`) and what it ran.

    Attributes:
        config: the configuration the pass ran (resolved).
        seed, begin, step: SUMO's seed (None: the configuration's), begin [s] and step [s].
        end: [s] the pass's last simulated time.
        data: the file's bytes.
    """

    config: Path
    seed: int | None
    begin: float
    step: float
    end: float
    data: bytes


def pass_route_args(path: Path) -> list[str]:
    """SUMO's options for the vehroute output that :func:`expand_flows` reads, written to ``path``."""
    return ["--vehroute-output", str(path), "--vehroute-output.sorted", "true",
            "--vehroute-output.intended-depart", "true", "--vehroute-output.write-unfinished", "true",
            "--vehroute-output.speedfactor", "true"]


@contextlib.contextmanager
def recording_pass_routes(session: SumoSession, *, begin: float) -> Iterator[None]:
    """Around the start and end of a nominal pass (``session`` not started yet): the pass writes the
    vehroute output its variants' exports take the flows' members from (:func:`pass_routes`).
    Nothing where the configuration declares a vehroute output of its own (these options would
    change what it writes) or where the pass ends with an error. ``begin`` [s]: the pass's."""
    if session.config is None or declares(session.config, "vehroute-output"):
        yield
        return
    with tempfile.TemporaryDirectory(prefix="coster-pass-routes-") as tmp:
        path = Path(tmp) / "pass.vehroute.xml"
        session.extra_args += pass_route_args(path)
        session.own_outputs.append(Path(tmp))  # held copies of the pass never write into it
        yield
        if path.is_file() and not session.is_running:
            remember_pass_routes(PassRoutes(session.config.resolve(), session.seed, begin, session.step_length,
                                            session.time, path.read_bytes()))


_PASS_ROUTES: list[PassRoutes] = []
MAX_PASS_ROUTES_KEPT = 4


def remember_pass_routes(routes: PassRoutes) -> None:
    """Keep a nominal pass's vehroute output for the exports of its variants in this process."""
    _PASS_ROUTES[:] = [r for r in _PASS_ROUTES if r.config != routes.config][-(MAX_PASS_ROUTES_KEPT - 1):]
    _PASS_ROUTES.append(routes)


def pass_routes(config: Path, *, seed: int | None, begin: float, step: float, end: float | None
                ) -> PassRoutes | None:
    """The kept vehroute output of a nominal pass of ``config`` with this seed, begin and step that
    ran at least to ``end`` [s] (None: to its own end is not known, so none), cut to ``end``; None
    where there is none."""
    if end is None:
        return None
    for r in reversed(_PASS_ROUTES):
        if (r.config == Path(config).resolve() and r.seed == seed and abs(r.begin - begin) < 1e-6
                and abs(r.step - step) < 1e-9 and r.end >= end - 1e-6):
            return dataclasses.replace(r, end=end)
    return None


def _run_showing_steps(cmd: list[str], config: Path, progress: Callable[[float, float], object],
                       timeout_s: float) -> subprocess.CompletedProcess[str]:
    """``cmd`` run with SUMO's step log on (every simulated second), each step it reports handed to
    ``progress`` as the seconds done since the configuration's begin. Its messages (stderr joined
    to stdout: one pipe cannot fill while the other is read) come back as stdout, the step log
    left out."""
    cfg = read_sumocfg(config)
    begin = cfg.begin or 0.0
    span = max((cfg.end or begin) - begin, 0.0)
    period = max(1, round(1.0 / (cfg.step_length or 1.0)))
    with subprocess.Popen([*cmd, "--no-step-log", "false", "--step-log.period", str(period)], stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, env=sumo_install.subprocess_env(), cwd=config.parent) as proc:
        assert proc.stdout is not None
        kept: list[bytes] = []
        deadline = time.monotonic() + timeout_s
        out = proc.stdout.fileno()
        for chunk in iter(lambda: os.read(out, 65536), b""):  # what SUMO wrote so far (b"": it ended)
            if time.monotonic() > deadline:
                proc.kill()
                raise subprocess.TimeoutExpired(cmd, timeout_s)
            steps = STEP_LOG.findall(chunk)
            if steps:
                progress(min(max(float(steps[-1]) - begin, 0.0), span), span)
            kept.append(STEP_LOG.sub(b"", chunk))
        proc.wait()
    return subprocess.CompletedProcess(cmd, proc.returncode, b"".join(kept).decode(errors="replace"), "")
