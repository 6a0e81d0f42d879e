"""The ``.sumocfg`` of a standalone SUMO export (:mod:`coster_sumo.exports.sumo`).

It carries the source configuration's own options (routing, lane-change, device and model options
change what the traffic does: SUMO's ``game/grid6`` sets ``weights.random-factor``) with the
settings of the pass on top: begin, end, step length, seed, the collision and teleport options,
plus what the FCD replay device needs. Left out of the source's options: its inputs (the export
names its copies by file name, so the folder runs from anywhere), its ``<output>`` section and
every other file output (a replay should not write into the folder unasked), a TraCI port
(plain ``sumo`` would wait for a client), ``random`` (the seed is the pass's) and its
``<gui_only>`` section, replaced by the export's own: ``gui.settings.xml`` (view centred on the
collision snapshot, 100 ms delay per step) and ``start`` false, so ``sumo-gui -c`` opens paused
on the scene. Plain ``sumo`` accepts and ignores those options. Options are compared by SUMO's own
names (``<b>`` is ``begin``, ``<tripinfo>`` is ``tripinfo-output``), since sumo refuses an option
set twice; options written straight under the source's root, which sumo also reads, go to a
``<source>`` section.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from defusedxml import ElementTree as SafeET

from coster_sumo.errors import InputError
from coster_sumo.formats.sumocfg import INPUT_KEYS, open_maybe_gzip, option_name
from coster_sumo.sim.sumo_options import RECOMMENDED_OPTIONS

GUI_SETTINGS_FILE = "gui.settings.xml"
GUI_DELAY_MS = 100  # [ms] sumo-gui's pause between 0.1 s steps: about real time
GUI_VIEW_SPAN_M = 60.0  # [m] zoom scale: a 1000 x 700 window then shows about 120 m around the snapshot
# options of the injection pass (SumoSession passes them) that decide what a contact does
PASS_OPTIONS = ("--collision.action", "--collision.mingap-factor", "--collision.check-junctions",
                "--time-to-teleport")
DROPPED = {"remote-port", "num-clients", "random", "log", "message-log", "error-log", "output-prefix",
           "save-configuration", "save-template", "save-schema", "configuration-file", "netstate-dump"}


FLAT_SECTION = "source"  # the export's section for the source's options that had none


def source_options(config: Path) -> list[tuple[str, str, str]]:
    """(section, option, value) of the source configuration that the export keeps (see the module
    docstring); sections and order as written, ``<gui_only>`` and the options named above left out."""
    with open_maybe_gzip(config) as fh:
        root = SafeET.parse(fh, forbid_dtd=True).getroot()
    out = []
    for section in root:
        sec = str(section.tag).split("}")[-1]
        if not isinstance(section.tag, str) or sec in ("gui_only", "output"):
            continue
        # sumo ignores the section names, and takes options written straight under the root too
        # (sumolib's RiLSA scenarios); those go to a section of their own
        flat = section.get("value") is not None and len(section) == 0
        options, sec = ([section], FLAT_SECTION) if flat else (list(section), sec)
        for el in options:
            if not isinstance(el.tag, str) or el.get("value") is None:
                continue
            key = option_name(el.tag.split("}")[-1])  # SUMO's own name: the export's options must not repeat it
            if key in INPUT_KEYS or key in DROPPED or key.endswith("-output") or "-output." in key:
                continue
            out.append((sec, key, str(el.get("value"))))
    return out


def source_option(config: Path, key: str) -> str | None:
    """The value of one option of the source configuration (None: not set)."""
    for _, k, v in source_options(config):
        if k == key:
            return v
    return None


def write_gui_settings(path: Path, centre: tuple[float, float], net_span_m: float) -> None:
    """sumo-gui view settings: centred on ``centre`` [m], zoomed by :data:`GUI_VIEW_SPAN_M`."""
    zoom = max(100.0, 100.0 * net_span_m / GUI_VIEW_SPAN_M)  # 100 % shows the whole net
    root = ET.Element("viewsettings")
    root.append(ET.Comment(" coster-sumo export: opens on the collision snapshot "))
    ET.SubElement(root, "viewport", {"zoom": f"{zoom:.1f}", "x": f"{centre[0]:.2f}", "y": f"{centre[1]:.2f}"})
    ET.SubElement(root, "delay", {"value": str(GUI_DELAY_MS)})
    ET.indent(root)
    ET.ElementTree(root).write(path, encoding="unicode", xml_declaration=True)


@dataclass(frozen=True)
class PassClock:
    """The time window, step and seed of a variant's pass, as its export replays it.

    Attributes:
        begin: [s] SUMO's begin as the configuration writes it (None: the source's).
        end: [s] the pass's last time (None: the source's).
        step: [s] the step length.
        seed: SUMO's seed (None: the source's).
    """

    begin: str | None
    end: float | None
    step: float
    seed: int | None

    def __post_init__(self) -> None:
        if not self.step > 0:
            raise InputError(f"the step length must be > 0 s, not {self.step}")


def write_export_config(path: Path, source: Path, names: dict[str, list[str]], clock: PassClock, *,
                        processing: dict[str, str], output: dict[str, str], fcd_file: str,
                        gui_settings: str | None) -> None:
    """Write the export's configuration (see the module docstring).

    Args:
        path: the .sumocfg to write.
        source: the configuration the variant was generated on.
        names: input option -> file names in the export folder (``net-file``, ``route-files``,
            ``additional-files``; the FCD vTypes first among the additional files).
        clock: the pass's time window [s], step [s] and seed.
        processing, output: further options of the export (they win over the source's).
        fcd_file: the FCD replay file.
        gui_settings: the sumo-gui settings file (None: none).
    """
    mine: dict[str, dict[str, str]] = {"input": {}, "time": {}, "processing": {}, "random_number": {},
                                       "output": dict(output), "report": {}, "fcd_replay_device": {}}
    for key in INPUT_KEYS:
        if names.get(key):
            mine["input"][key] = ",".join(names[key])
    if clock.begin is not None:
        mine["time"]["begin"] = clock.begin
    if clock.end is not None:
        mine["time"]["end"] = f"{clock.end:.3f}"
    mine["time"]["step-length"] = f"{clock.step:g}"
    for key in PASS_OPTIONS:
        mine["processing"][key.lstrip("-")] = RECOMMENDED_OPTIONS[key]
    mine["processing"].update(processing)
    if clock.seed is not None:
        mine["random_number"]["seed"] = str(int(clock.seed))
    # as in the pass: the device's placements warn every step (jumps, emergency braking); contacts
    # still reach --collision-output (pass --no-warnings false to see them all)
    mine["report"].update({"no-step-log": "true", "no-warnings": "true"})
    mine["fcd_replay_device"]["device.fcd-replay.files"] = fcd_file
    taken = {k for opts in mine.values() for k in opts}
    kept: dict[str, dict[str, str]] = {}
    for sec, key, value in source_options(source):
        if key not in taken:
            kept.setdefault(sec, {})[key] = value
    root = ET.Element("configuration")
    root.append(ET.Comment(" coster-sumo export of one variant: `sumo -c " + path.name + "` (or sumo-gui) plays "
                           "it, the adversary driven by SUMO's FCD replay device from " + fcd_file + " "))
    for sec in dict.fromkeys([*mine, *kept]):
        opts = {**kept.get(sec, {}), **mine.get(sec, {})}
        if opts:
            el = ET.SubElement(root, sec)
            for key, value in opts.items():
                ET.SubElement(el, key, {"value": value})
    if gui_settings is not None:
        gui = ET.SubElement(root, "gui_only")
        ET.SubElement(gui, "gui-settings-file", {"value": gui_settings})
        ET.SubElement(gui, "start", {"value": "false"})
    ET.indent(root)
    ET.ElementTree(root).write(path, encoding="unicode", xml_declaration=True)
