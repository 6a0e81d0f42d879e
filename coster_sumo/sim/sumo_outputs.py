"""Where SUMO's own outputs go: never where a configuration declares them (docs/sumo.md, "Outputs").

A configuration may ask SUMO to write files: options of the ``.sumocfg`` (``fcd-output``,
``tripinfo-output``, detector-free ``edgedata-output``, logs...) and attributes of its additional
files (an induction loop's ``file``, a calibrator's ``output``, a timed event's ``dest``...). Every
pass coster-sumo makes (the nominal pass, held copies, proofs, injections) would write them as
declared, over whatever the user keeps there. So every session's command line names, for each
output the configuration declares, a file in a folder of ours instead:

- options of the configuration: overridden on the command line (it wins over the file);
- additional files that declare outputs: a staged copy with those attributes rewritten (and the
  inputs it names made absolute) replaces the file in ``-a``.

SUMO's ``--output-prefix`` cannot do it: it is prepended to the last path component of each output,
so an output with an absolute path stays in its folder, and a prefix with a folder in it is refused
for absolute outputs (measured, docs/sumo.md). The folder is the caller's (``run`` keeps the nominal
pass's outputs under ``OUT/sumo-outputs``) or a temporary one per process, removed at its exit.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from defusedxml import ElementTree as SafeET

from coster_sumo.errors import InputError
from coster_sumo.formats.sumocfg import open_maybe_gzip, option_name, read_sumocfg, split_files
from coster_sumo.infra.staging import staging_folder

# Options of sumo 1.28 that write a file (type FILE in `sumo --save-template t.xml
# --save-template.commented`, sections output, report, routing, taxi device; and device.ssm.file /
# device.toc.file, typed STR there but written all the same). The inputs of the output section
# (filter-edges.input-file, jupedsim files) are not here.
OUTPUT_OPTIONS = frozenset({
    "save-configuration", "save-template", "save-schema",
    "netstate-dump", "emission-output", "battery-output", "elechybrid-output", "chargingstations-output",
    "overheadwiresegments-output", "substations-output", "fcd-output", "person-fcd-output", "full-output",
    "queue-output", "vtk-output", "amitran-output", "summary-output", "person-summary-output",
    "tripinfo-output", "personinfo-output", "vehroute-output", "personroute-output", "link-output",
    "railsignal-block-output", "railsignal-vehicle-output", "bt-output", "lanechange-output", "stop-output",
    "collision-output", "edgedata-output", "lanedata-output", "statistic-output", "deadlock-output",
    "save-state.files", "device.rerouting.output", "log", "message-log", "error-log",
    "device.taxi.dispatch-algorithm.output", "device.taxi.idle-algorithm.output",
    "device.ssm.file", "device.toc.file", "gui-testing.setting-output",
})
# Per-step dumps of every vehicle: never written, not even by a pass that keeps the others. SUMO
# crashed (SIGSEGV) stepping a proof pass of a configuration with fcd-output on (main at bc0dc27
# too, --from-begin), and the run writes every vehicle's track itself (trajectories.npz).
PER_STEP_OUTPUTS = frozenset({"fcd-output", "person-fcd-output", "netstate-dump", "full-output", "emission-output",
                              "vtk-output", "amitran-output"})
# saving states at times writes files named after this prefix (default "state", in the working folder)
STATE_TRIGGERS = ("save-state.times", "save-state.period")
# The additional-file elements that write a file, and the attribute naming it (additional_file.xsd).
OUTPUT_ATTRIBUTES: dict[str, str] = {
    **dict.fromkeys(("e1Detector", "inductionLoop", "e2Detector", "laneAreaDetector", "e3Detector",
                     "entryExitDetector", "instantInductionLoop", "edgeData", "laneData", "edgeRelations",
                     "tazRelations", "routeProbe", "vTypeProbe"), "file"),
    "calibrator": "output", "timedEvent": "dest",
}
INPUT_ATTRIBUTES = ("file", "href")  # on other elements (rerouter, variableSpeedSign, include): inputs
OUTPUT_PARAMS = ("device.ssm.file", "device.toc.file")  # <param key=... value=FILE> of a vType/vehicle
NOWHERE = ("nul", "/dev/null")  # outputs SUMO discards


@dataclass(frozen=True)
class Redirect:
    """One output of a configuration: what declared it, where SUMO would write it, where it goes."""

    source: str  # "c.sumocfg: fcd-output" or "det.add.xml: inductionLoop d1"
    declared: str  # the path as SUMO resolves it (relative: against the declaring file's folder)
    written: str  # the file this session writes instead


@dataclass
class Sandbox:
    """Where one session's outputs go: ``args`` for its command line, ``additional`` (the
    configuration's additional files, staged where they declare outputs) and what was redirected."""

    folder: Path | None  # None: every output is discarded
    args: list[str] = field(default_factory=list)
    config: Path | None = None  # a staged copy of the configuration to load instead (discarding)
    additional: list[Path] = field(default_factory=list)
    staged: bool = False  # some additional file was replaced by a staged copy
    redirects: list[Redirect] = field(default_factory=list)
    _names: set[str] = field(default_factory=set)

    def discard(self, declared: str, base: Path, source: str) -> None:
        """Record an output that is not written at all."""
        for v in split_files(declared):
            self.redirects.append(Redirect(source, v if os.path.isabs(v) else str(base / v), os.devnull))

    def target(self, declared: str, base: Path, source: str) -> str:
        """The file of ours for an output declared as ``declared`` (relative to ``base``)."""
        if declared.strip().lower() in NOWHERE:
            return declared
        path = declared if declared in ("stdout", "-") or os.path.isabs(declared) else str(base / declared)
        if self.folder is None:
            self.redirects.append(Redirect(source, path, os.devnull))
            return os.devnull
        name = Path(declared).name or "output"
        stem, dot, ext = name.partition(".")
        k = 1
        while name in self._names:
            k += 1
            name = f"{stem}-{k}{dot}{ext}"
        self._names.add(name)
        self.folder.mkdir(parents=True, exist_ok=True)
        written = str(self.folder / name)
        self.redirects.append(Redirect(source, path, written))
        return written


@dataclass
class KeptOutputs:
    """The folder the nominal pass of a command keeps SUMO's outputs in, and what went there."""

    folder: Path
    redirects: tuple[Redirect, ...] = ()

    def write_listing(self) -> Path | None:
        """``folder/declared.json``: each output the configuration declares and the file of the
        folder it went to (None: it declares none)."""
        if not self.redirects:
            return None
        path = self.folder / "declared.json"
        rows = [{"declared_by": r.source, "declared": r.declared,
                 "kept_as": None if r.written == os.devnull else os.path.relpath(r.written, self.folder)}
                for r in self.redirects]
        path.write_text(json.dumps(rows, indent=1) + "\n")
        return path


_NOMINAL: list[KeptOutputs] = []


@contextlib.contextmanager
def keep_nominal_outputs(folder: Path) -> Iterator[KeptOutputs]:
    """While inside: the nominal pass (:func:`nominal_outputs`) writes its outputs into ``folder``."""
    kept = KeptOutputs(Path(folder))
    _NOMINAL.append(kept)
    try:
        yield kept
    finally:
        _NOMINAL.remove(kept)


def nominal_outputs() -> KeptOutputs | None:
    """Where a nominal pass keeps its SUMO outputs (None: a temporary folder)."""
    return _NOMINAL[-1] if _NOMINAL else None


def declares(config: Path, option: str) -> bool:
    """Whether ``config`` sets ``option`` (SUMO's long name, e.g. ``vehroute-output``) to something."""
    return bool(_config_options(config).get(option_name(option), "").strip())


def _config_options(config: Path) -> dict[str, str]:
    """Every option a configuration sets, under SUMO's own names (both spellings, as SUMO reads them)."""
    with open_maybe_gzip(config) as fh:
        root = SafeET.parse(fh, forbid_dtd=True).getroot()
    values: dict[str, str] = {}
    for el in root.iter():
        if el.get("value") is not None:
            values[option_name(str(el.tag).split("}")[-1])] = str(el.get("value"))
        for attr, val in el.attrib.items():
            if attr not in ("value", "type", "help", "synonymes"):
                values[option_name(attr)] = val
    return values


def _stage_additional(path: Path, box: Sandbox) -> Path:
    """``path``, or a staged copy of it whose outputs go to ``box`` (when it declares any)."""
    try:
        with open_maybe_gzip(path) as fh:
            tree = SafeET.parse(fh, forbid_dtd=True)
    except Exception as exc:  # noqa: BLE001 - defusedxml raises several types; all mean "bad file"
        raise InputError(f"{path}: not a readable additional file ({type(exc).__name__}: {exc})") from None
    changed = False
    for el in tree.getroot().iter():
        tag = str(el.tag).split("}")[-1]
        attr = OUTPUT_ATTRIBUTES.get(tag)
        if attr is not None and el.get(attr):
            el.set(attr, box.target(str(el.get(attr)), path.parent, f"{path.name}: {tag} {el.get('id', '')}".strip()))
            changed = True
        elif tag == "param" and el.get("key") in OUTPUT_PARAMS and el.get("value"):
            el.set("value", box.target(str(el.get("value")), path.parent, f"{path.name}: param {el.get('key')}"))
            changed = True
        else:
            for a in INPUT_ATTRIBUTES:  # the staged copy lives elsewhere: its inputs by absolute path
                v = el.get(a)
                if v and not os.path.isabs(v):
                    el.set(a, str((path.parent / v).resolve()))
    if not changed:  # by its absolute path: a staged configuration that names it lives elsewhere
        return path.resolve()
    out = Path(tempfile.mkdtemp(prefix="add-", dir=staging_folder())) / path.name.removesuffix(".gz")
    tree.write(out, encoding="unicode", xml_declaration=True)
    box.staged = True
    return out


_BOXES: dict[tuple[Any, ...], Sandbox] = {}


def _version(path: Path) -> tuple[str, int, int]:
    st = path.stat()
    return str(path), st.st_mtime_ns, st.st_size


def sandbox(config: Path | None, additional: Sequence[Path] = (), folder: Path | None = None) -> Sandbox:
    """Where every output ``config`` and the ``additional`` files loaded after its own declare go:
    into ``folder``, or (None) nowhere; see the module docstring. Cached per file versions and
    folder (staging parses every additional file)."""
    files = [*(read_sumocfg(config).additional_files if config is not None else ()), *additional]
    key = (str(folder), *(_version(p) for p in ([config] if config else []) + files if p.is_file()))
    if key in _BOXES:
        return _BOXES[key]
    box = Sandbox(folder=None if folder is None else Path(folder))
    box.additional = [_stage_additional(p, box) if p.is_file() else p for p in files]
    if config is None:
        pass
    elif box.folder is None:
        box.config = _quiet_copy(config, box, OUTPUT_OPTIONS | set(STATE_TRIGGERS))
    else:
        box.config = _quiet_copy(config, box, PER_STEP_OUTPUTS)
        values = _config_options(config)
        for name, value in values.items():
            if name in OUTPUT_OPTIONS - PER_STEP_OUTPUTS and value.strip():
                written = [box.target(v, config.parent, f"{config.name}: {name}") for v in split_files(value)]
                box.args += [f"--{name}", ",".join(written)]
        if any(values.get(t, "").strip() for t in STATE_TRIGGERS):
            prefix = values.get("save-state.prefix", "state")
            box.args += ["--save-state.prefix",
                         box.target(prefix, config.parent, f"{config.name}: save-state.prefix")]
    _BOXES[key] = box
    return box


def _quiet_copy(config: Path, box: Sandbox, drop: frozenset[str] | set[str]) -> Path | None:
    """A copy of ``config`` without the options ``drop`` names (SUMO cannot unset an output from the
    command line: ``--fcd-output ""`` is refused), its ``<gui_only>`` section, and with the staged
    additional files; it names every input by its absolute path. None when it needs no copy."""
    with open_maybe_gzip(config) as fh:
        tree = SafeET.parse(fh, forbid_dtd=True)
    root = tree.getroot()
    changed = box.staged
    for parent in list(root.iter()):
        for el in list(parent):
            tag = str(el.tag).split("}")[-1]
            name = option_name(tag)
            if tag == "gui_only" or (name in drop and el.get("value", "").strip()):
                if name in drop:
                    box.discard(str(el.get("value")), config.parent, f"{config.name}: {name}")
                parent.remove(el)
                changed = True
            elif name == "additional-files" and box.staged:
                el.set("value", ",".join(str(p) for p in box.additional))
    for el in root.iter():
        for attr in list(el.attrib):
            if option_name(attr) in drop and el.get(attr, "").strip():
                box.discard(str(el.get(attr)), config.parent, f"{config.name}: {option_name(attr)}")
                del el.attrib[attr]
                changed = True
            elif option_name(attr) == "additional-files" and box.staged:
                el.set(attr, ",".join(str(p) for p in box.additional))
        value = el.get("value")
        if value and not (box.staged and option_name(str(el.tag)) == "additional-files"):
            # only a list that names files is rewritten: other lists (insertion-checks "collision
            # leaderGap ...") keep their own separators, which SUMO may need (it refused the commas)
            parts = split_files(value)
            moved = [str((config.parent / f).resolve()) if (config.parent / f).is_file() else f for f in parts]
            if moved != parts:
                el.set("value", ",".join(moved))
    if not changed:
        return None
    out = Path(tempfile.mkdtemp(prefix="cfg-", dir=staging_folder())) / config.name.removesuffix(".gz")
    tree.write(out, encoding="unicode", xml_declaration=True)
    return out


def detach_outputs(folder: Path) -> int:
    """In a forked copy of a simulation: point every open file under ``folder`` at /dev/null, so the
    copy's steps do not write into the outputs its parent keeps. Returns how many were detached
    (0 where ``/proc/self/fd`` does not exist)."""
    fds = Path("/proc/self/fd")
    if not fds.is_dir():
        return 0
    root = str(Path(folder).resolve())
    n = 0
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        for entry in list(fds.iterdir()):
            with contextlib.suppress(OSError, ValueError):
                fd = int(entry.name)
                if fd != null and os.readlink(entry).startswith(root + os.sep):
                    os.dup2(null, fd)
                    n += 1
    finally:
        os.close(null)
    return n


