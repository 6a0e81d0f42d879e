"""Running netconvert on the plain XML files, and reading back what the net it wrote contains.

The options (:data:`NETCONVERT_OPTIONS`) keep WOMD's coordinates and cut as little of the WOMD
lanes as netconvert allows (docs/sumo.md §2); :func:`read_net` parses the lanes, connections with
their internal-lane chains, and traffic lights that the later steps
(:mod:`converters.restore_geometry`, :mod:`converters.fidelity`) compare with the lane graph.
"""

from __future__ import annotations

import subprocess
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from defusedxml import ElementTree as SafeET

from coster_sumo.errors import CosterError
from coster_sumo.infra import sumo_install
from coster_sumo.infra.outdir import raise_if_disk_full

NETCONVERT_OPTIONS = [
    "--offset.disable-normalization", "true",  # keep WOMD coordinates (no shift to the origin)
    "--precision", "4",                        # 0.1 mm output instead of 1 cm
    # Junction polygons from the lane end points, and no pushing lane ends apart where they overlap:
    # the least cutting of WOMD lanes (on the real samples: 94-100 % of lanes within 0.5 m before
    # set_womd_geometry). --junctions.minimal-shape (docs/sumo.md §2, right for lane-per-edge
    # chains) builds a tiny polygon around the node's centroid and *extends* every lane of an
    # intersection up to it (measured: 86 % / 72 % of lanes matched on the two TFRecord samples).
    "--junctions.endpoint-shape", "true",
    "--geometry.avoid-overlap", "false",
    "--no-turnarounds", "true",                # only the connections WOMD has
    "--no-warnings", "true",
]


class ConversionError(CosterError):
    """A scene that cannot be converted (bad map, netconvert failure): one line naming the scene."""

    exit_code = 1


def run_netconvert(nod: Path, edg: Path, con: Path, net: Path) -> None:
    """Run netconvert on the plain files; raise :class:`ConversionError` with SUMO's message."""
    cmd = [sumo_install.binary("netconvert"), "-n", str(nod), "-e", str(edg), "-x", str(con), "-o", str(net),
           *NETCONVERT_OPTIONS]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=sumo_install.subprocess_env())
    if proc.returncode != 0 or not net.exists():
        err = [ln for ln in (proc.stderr + proc.stdout).splitlines() if ln.startswith("Error")]
        msg = " ".join(err[:2]) or (proc.stderr.strip().splitlines() or ["no message"])[-1]
        raise ConversionError(f"netconvert failed: {msg}")


# ----------------------------------------------------------------------------- reading the net back

def _parse_xml(path: Path) -> Any:
    """``path`` parsed with defusedxml; a file that is not plain XML raises :class:`ConversionError`."""
    try:
        return SafeET.parse(path, forbid_dtd=True)
    except Exception as exc:  # noqa: BLE001 - ParseError, DTDForbidden, EntitiesForbidden, OSError
        raise_if_disk_full(path)  # a net truncated by a full disk is the disk's fault, not the net's
        raise ConversionError(f"{path.name}: not a readable SUMO net ({type(exc).__name__}: {exc})") from None


@dataclass(slots=True)
class NetInfo:
    """What the written network contains, read back from ``.net.xml``.

    Attributes:
        lane_shapes: SUMO lane id -> (n, 2) shape.
        connections: (from_lane, to_lane) -> (via lane chain, tl id or "", link index or -1).
        tls: tls id -> number of link indices.
    """

    lane_shapes: dict[str, np.ndarray]
    connections: dict[tuple[str, str], tuple[list[str], str, int]]
    tls: dict[str, int]


def read_net(net: Path) -> NetInfo:
    """Parse lanes, connections (with their internal-lane chain) and traffic lights of a net.

    Read with ``defusedxml`` (no DTD, no entities), like every XML file coster-sumo parses itself.
    """
    root = _parse_xml(net).getroot()
    shapes: dict[str, np.ndarray] = {}
    for e in root.iter("edge"):
        for ln in e.iter("lane"):
            pts = [tuple(map(float, p.split(",")[:2])) for p in ln.get("shape", "").split()]
            shapes[ln.get("id", "")] = np.asarray(pts, np.float64).reshape(-1, 2)
    raw: dict[tuple[str, int], list[ET.Element]] = {}
    for c in root.iter("connection"):
        raw.setdefault((c.get("from", ""), int(c.get("fromLane", "0"))), []).append(c)
    conns: dict[tuple[str, str], tuple[list[str], str, int]] = {}
    for (frm, fl), items in raw.items():
        if frm.startswith(":"):
            continue
        for c in items:
            to_lane = f"{c.get('to')}_{c.get('toLane')}"
            chain: list[str] = []
            via = c.get("via")
            while via and len(chain) < 10:  # internal lanes split at conflict points chain by via
                chain.append(via)
                edge, _, idx = via.rpartition("_")
                nxt = [x for x in raw.get((edge, int(idx)), [])]
                via = nxt[0].get("via") if nxt else None
            conns[(f"{frm}_{fl}", to_lane)] = (chain, c.get("tl", ""), int(c.get("linkIndex", "-1")))
    tls: dict[str, int] = {}
    for t in root.iter("tlLogic"):
        phases = list(t.iter("phase"))
        tls[t.get("id", "")] = len(phases[0].get("state", "")) if phases else 0
    return NetInfo(shapes, conns, tls)
