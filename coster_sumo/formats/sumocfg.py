"""The one reader of SUMO configuration files (``.sumocfg``) and the well-formedness check of inputs.

A ``.sumocfg`` is small XML: ``<input>`` names the net, route and additional files (comma or space
separated, relative to the configuration's folder), ``<time>`` the begin, end and step length. Any
element may also carry its value as an attribute of the same name; both spellings are read, and so
is every other name SUMO knows an option by (``<net>``, ``<n>``: :data:`OPTION_SYNONYMS`). Files
may be gzip-compressed (SUMO reads ``.gz`` inputs, and so do we). Parsing goes through
``defusedxml``: configuration files are user input and may come from anywhere.
"""

from __future__ import annotations

import atexit
import gzip
import os
import shutil
import tempfile
import xml.parsers.expat
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from defusedxml import ElementTree as SafeET

from coster_sumo.errors import InputError, not_found

INPUT_KEYS = ("net-file", "route-files", "additional-files")

# SUMO knows most options under several names, and a configuration may use any of them
# (`<net value=...>` and `<n value=...>` are `<net-file>`; sumolib's RiLSA scenarios write `<net>`).
# Every other name -> the name `sumo --save-template` writes, for the options of sumo 1.28 that have
# more than one (its `--print-options` lists them: `n (net, net-file)`). docs/sumo.md, "Option names".
OPTION_SYNONYMS = {
    "n": "net-file", "net": "net-file", "r": "route-files", "routes": "route-files",
    "a": "additional-files", "additional": "additional-files", "b": "begin", "e": "end",
    "c": "configuration-file", "configuration": "configuration-file",
    "C": "save-configuration", "save-config": "save-configuration",
    "save-config.relative": "save-configuration.relative", "save-template.commented": "save-commented",
    "W": "no-warnings", "suppress-warnings": "no-warnings", "v": "verbose", "l": "log", "log-file": "log",
    "X": "xml-validation", "H": "human-readable-time", "t": "duration-log.statistics",
    "no-duration-log": "duration-log.disable", "?": "help", "V": "version",
    "srand": "seed", "abs-rand": "random",
    "g": "gui-settings-file", "B": "breakpoints", "D": "demo", "G": "game", "Q": "quit-on-end", "S": "start",
    "T": "disable-textures", "d": "delay", "N": "alternative-net-file",
    "w": "weight-files", "weights": "weight-files", "measure": "weight-attribute", "x": "weight-attribute",
    "m": "edgedata-files", "data-files": "edgedata-files", "s": "route-steps",
    "carfollow.model": "default.carfollowmodel", "meso.ignore-lanes.by-vclass": "meso-ignore-lanes-by-vclass",
    "railsignal.moving-block": "railsignal-moving-block",
    "ndump": "netstate-dump", "netstate": "netstate-dump", "netstate-output": "netstate-dump",
    "dump-empty-edges": "netstate-dump.empty-edges", "netstate.empty-edges": "netstate-dump.empty-edges",
    "netstate-output.empty-edges": "netstate-dump.empty-edges", "dump-precision": "netstate-dump.precision",
    "netstate.precision": "netstate-dump.precision", "netstate-output.precision": "netstate-dump.precision",
    "summary": "summary-output", "tripinfo": "tripinfo-output", "statistics-output": "statistic-output",
    "personinfo": "personinfo-output", "person-fcd": "person-fcd-output", "personroutes": "personroute-output",
    "vehroutes": "vehroute-output", "vehroutes.dua": "vehroute-output.dua",
    "vehroutes.exit-times": "vehroute-output.exit-times",
    "vehroutes.intended-depart": "vehroute-output.intended-depart",
    "vehroutes.last-route": "vehroute-output.last-route", "vehroutes.route-length": "vehroute-output.route-length",
    "vehroutes.sorted": "vehroute-output.sorted",
    "device.fcd-replay.file": "device.fcd-replay.files", "taxi.vclasses": "device.taxi.vclasses",
    "routing-threads": "device.rerouting.threads", "with-taz": "device.rerouting.with-taz",
    "device.routing.with-taz": "device.rerouting.with-taz", "device.routing.period": "device.rerouting.period",
    "device.routing.pre-period": "device.rerouting.pre-period",
    "device.routing.adaptation-interval": "device.rerouting.adaptation-interval",
    "device.routing.adaptation-steps": "device.rerouting.adaptation-steps",
    "device.routing.adaptation-weight": "device.rerouting.adaptation-weight",
    "person-device.routing.period": "person-device.rerouting.period",
    **{f"{d}.knownveh": f"{d}.explicit" for d in (
        "device.battery", "device.bluelight", "device.btreceiver", "device.btsender", "device.driverstate",
        "device.elechybrid", "device.emissions", "device.example", "device.fcd-replay", "device.fcd",
        "device.friction", "device.glosa", "device.rerouting", "device.ssm", "device.stationfinder",
        "device.taxi", "device.toc", "device.tripinfo", "device.vehroute", "person-device.btreceiver",
        "person-device.btsender", "person-device.fcd", "person-device.rerouting")},
}


def option_name(name: str) -> str:
    """SUMO's own name of an option spelled ``name`` (:data:`OPTION_SYNONYMS`; unknown names as given)."""
    return OPTION_SYNONYMS.get(name, name)


@dataclass(frozen=True)
class SumoConfig:
    """What coster-sumo reads from a ``.sumocfg``.

    Attributes:
        path: the configuration file.
        net_files, route_files, additional_files: inputs, resolved against the file's folder.
        begin, end: [s] the configured simulation window (None where the file does not say).
        step_length: [s] the configured step (None: SUMO's default, 1 s).
    """

    path: Path
    net_files: tuple[Path, ...] = ()
    route_files: tuple[Path, ...] = ()
    additional_files: tuple[Path, ...] = ()
    begin: float | None = None
    end: float | None = None
    step_length: float | None = None
    gui_only: tuple[str, ...] = ()  # options of its <gui_only> section (plain sumo may not know them)
    load_state: tuple[Path, ...] = ()  # saved states it starts from (they hold vehicles of their own)

    def inputs(self) -> dict[str, list[Path]]:
        """``{"net-file": [...], "route-files": [...], "additional-files": [...]}``."""
        return {"net-file": list(self.net_files), "route-files": list(self.route_files),
                "additional-files": list(self.additional_files)}

    @property
    def net_file(self) -> Path:
        """The (first) net file; :class:`InputError` when the configuration names none."""
        if not self.net_files:
            raise InputError(f"{self.path}: the configuration names no net-file")
        return self.net_files[0]

    @property
    def has_demand(self) -> bool:
        """True when the configuration names route files (its own traffic)."""
        return bool(self.route_files)


def open_maybe_gzip(path: Path) -> IO[bytes]:
    """``path`` opened for binary reading, decompressed when it is gzip (by its magic bytes)."""
    with path.open("rb") as fh:
        magic = fh.read(2)
    if magic == b"\x1f\x8b":
        return gzip.open(path, "rb")  # type: ignore[return-value]  # GzipFile reads bytes like any IO
    return path.open("rb")


_XML_OK: set[tuple[str, int, int]] = set()


def check_xml(path: Path, what: str, referenced_by: Path | None = None) -> None:
    """Existence and well-formedness of an XML input (a truncated net crashes libsumo, rc 139).

    A file that passed is not parsed again until it changes (restarts in a batch stay cheap).
    Entity declarations are refused (no input of SUMO's needs them; they are how XML bombs work).
    """
    via = f" (referenced by {referenced_by})" if referenced_by is not None else ""
    if not path.is_file():
        raise not_found(path, referenced_by=referenced_by)
    st = path.stat()
    key = (str(path.resolve()), st.st_mtime_ns, st.st_size)
    if key in _XML_OK:
        return
    parser = xml.parsers.expat.ParserCreate()

    def refuse_entity(name: str, *_args: object) -> None:
        raise InputError(f"{path}: {what} declares an XML entity ({name!r}); refused{via}")

    parser.EntityDeclHandler = refuse_entity
    try:
        with open_maybe_gzip(path) as fh:
            parser.ParseFile(fh)
    except xml.parsers.expat.ExpatError as exc:
        raise InputError(f"{path}: {what} is not valid XML ({exc}){via}") from None
    except (OSError, EOFError, zlib.error) as exc:  # also a damaged gzip stream
        raise InputError(f"{path}: cannot read {what} ({exc}){via}") from None
    _XML_OK.add(key)


def split_files(value: str) -> list[str]:
    """File names of a SUMO list option (comma and/or space separated)."""
    return [v for v in value.replace(",", " ").split() if v]


def parse_time(text: str, where: str) -> float:
    """A SUMO time value: seconds (``"3600"``, ``"0.1"``) or ``[[D:]H:]M:S``."""
    try:
        parts = [float(p) for p in text.strip().split(":")]
    except ValueError:
        parts = []
    if not 1 <= len(parts) <= 4:
        raise InputError(f"{where}: {text!r} is not a time (seconds or H:M:S)")
    factors = (86400.0, 3600.0, 60.0, 1.0)[4 - len(parts):]  # D:H:M:S, H:M:S, M:S or S
    return float(sum(f * v for f, v in zip(factors, parts, strict=True)))


_CACHE: dict[tuple[str, int, int], SumoConfig] = {}


def read_sumocfg(path: str | Path) -> SumoConfig:
    """Read a ``.sumocfg`` (cached per file version). One :class:`InputError` line per problem."""
    path = Path(path)
    check_xml(path, "SUMO configuration")
    st = path.stat()
    key = (str(path), st.st_mtime_ns, st.st_size)  # as spelled: the inputs are resolved against it
    if key in _CACHE:
        return _CACHE[key]
    try:
        with open_maybe_gzip(path) as fh:
            root = SafeET.parse(fh, forbid_dtd=True).getroot()
    except Exception as exc:  # noqa: BLE001 - defusedxml raises several types; all mean "bad file"
        raise InputError(f"{path}: not a readable SUMO configuration ({type(exc).__name__}: {exc})") from None
    values: dict[str, str] = {}
    gui_only = tuple(str(el.tag) for sec in root.iter("gui_only") for el in sec)
    for el in root.iter():
        tag = option_name(str(el.tag).split("}")[-1])
        if el.get("value") is not None:
            values[tag] = str(el.get("value"))
        for attr, val in el.attrib.items():  # <input net-file="..."/> spelling
            name = option_name(attr)
            if name in INPUT_KEYS or name in ("begin", "end", "step-length"):
                values.setdefault(name, val)
    files = {k: tuple(path.parent / f for f in split_files(values.get(k, ""))) for k in INPUT_KEYS}

    def time_of(k: str) -> float | None:
        return parse_time(values[k], f"{path}: <{k}>") if values.get(k, "").strip() else None

    cfg = SumoConfig(path=path, net_files=files["net-file"], route_files=files["route-files"],
                     additional_files=files["additional-files"], begin=time_of("begin"), end=time_of("end"),
                     step_length=time_of("step-length"), gui_only=gui_only,
                     load_state=tuple(path.parent / f for f in split_files(values.get("load-state", ""))))
    _CACHE[key] = cfg
    return cfg


def config_files(config: Path) -> list[Path]:
    """The configuration and the files it names (only itself where it cannot be read): the inputs
    an output folder must hold none of."""
    try:
        cfg = read_sumocfg(config)
    except InputError:
        return [config]
    return [config, *cfg.net_files, *cfg.route_files, *cfg.additional_files]


def headless_copy(path: str | Path, folder: Path) -> Path:
    """A copy of a configuration without its ``<gui_only>`` section, written into ``folder``.

    Some configurations made for sumo-gui carry options plain ``sumo`` refuses (``osg-view``). The
    copy names every file the original names by its absolute path, so it runs from anywhere.
    """
    path = Path(path)
    with open_maybe_gzip(path) as fh:
        tree = SafeET.parse(fh, forbid_dtd=True)
    root = tree.getroot()
    for sec in list(root.iter("gui_only")):
        for parent in root.iter():
            if sec in list(parent):
                parent.remove(sec)
    for el in root.iter():
        value = el.get("value")
        if value and any((path.parent / f).exists() for f in split_files(value)):
            el.set("value", ",".join(str((path.parent / f).resolve()) if (path.parent / f).exists() else f
                                     for f in split_files(value)))
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / path.name.removesuffix(".gz")
    tree.write(out, encoding="unicode", xml_declaration=True)
    return out


_HEADLESS: dict[tuple[str, int], Path] = {}


def runnable_config(config: Path) -> Path:
    """``config``, or a copy of it without its sumo-gui options when it has some (see
    :func:`headless_copy`); copies live in a temporary folder."""
    if not read_sumocfg(config).gui_only:
        return config
    key = (str(config.resolve()), config.stat().st_mtime_ns)
    if key not in _HEADLESS:
        folder = Path(tempfile.mkdtemp(prefix="coster-headless-"))
        owner = os.getpid()

        def remove() -> None:
            if os.getpid() == owner:  # not from forked copies
                shutil.rmtree(folder, ignore_errors=True)

        atexit.register(remove)
        _HEADLESS[key] = headless_copy(config, folder)
    return _HEADLESS[key]
