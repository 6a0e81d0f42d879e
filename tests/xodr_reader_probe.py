"""Run one third-party OpenDRIVE reader on .xodr files and print what it found as JSON.

Run with the Python of the reader's own environment (``make xodr-readers`` builds them; the readers
pin versions of lxml, numpy and protobuf that the project's environment cannot share):

    .venv-xodr-asam/bin/python tests/xodr_reader_probe.py asam FILE...
    .venv-xodr-readers/bin/python tests/xodr_reader_probe.py commonroad FILE...
    .venv-xodr-readers/bin/python tests/xodr_reader_probe.py pyxodr FILE...

One JSON object per file and line: ``{"file", "reader", ...}`` with, for ``asam``, each checker's
status and its issues by level; for ``commonroad``, the lanelet count and the ids of lanelets whose
polygon is not valid (or the error that stopped the conversion); for ``pyxodr``, roads and lanes read
and the roads whose lanes could not be computed.
"""

from __future__ import annotations

import json
import logging
import sys
import tempfile
import warnings
from pathlib import Path


def asam(path: Path) -> dict:
    from qc_baselib import Configuration, Result
    from qc_opendrive import constants
    from qc_opendrive import main as checker

    with tempfile.TemporaryDirectory() as tmp:
        cfg = Path(tmp) / "config.xml"
        cfg.write_text(f'<?xml version="1.0"?><Config><Param name="InputFile" value="{path}"/>'
                       f'<CheckerBundle application="{constants.BUNDLE_NAME}">'
                       f'<Param name="resultFile" value="{Path(tmp) / "result.xqar"}"/></CheckerBundle></Config>')
        config = Configuration()
        config.load_from_file(str(cfg))
        result = Result()
        result.register_checker_bundle(name=constants.BUNDLE_NAME, description="", version=constants.BUNDLE_VERSION,
                                       summary="")
        result.set_result_version(version=constants.BUNDLE_VERSION)
        checker.run_checks(config, result)
    checkers = {}
    for ch in result.get_checker_bundle_result(constants.BUNDLE_NAME).checkers:
        levels: dict[str, int] = {}
        for issue in ch.issues:
            levels[issue.level.name] = levels.get(issue.level.name, 0) + 1
        checkers[ch.checker_id] = {"status": str(ch.status.value), "summary": ch.summary, "issues": levels}
    return {"checkers": checkers}


def commonroad(path: Path) -> dict:
    from crdesigner.map_conversion.map_conversion_interface import opendrive_to_commonroad

    try:
        scenario = opendrive_to_commonroad(path)
    except Exception as exc:  # noqa: BLE001 - what stopped the reader is the finding
        return {"error": f"{type(exc).__name__}: {exc}"}
    lanelets = scenario.lanelet_network.lanelets
    return {"lanelets": len(lanelets),
            "invalid": [int(ll.lanelet_id) for ll in lanelets if not ll.polygon.shapely_object.is_valid]}


def pyxodr(path: Path) -> dict:
    import numpy as np
    from pyxodr.road_objects.network import RoadNetwork

    try:
        roads = RoadNetwork(str(path)).get_roads()
    except Exception as exc:  # noqa: BLE001
        return {"error": f"{type(exc).__name__}: {exc}"}
    lanes, failed = 0, []
    for road in roads:
        try:
            for section in road.lane_sections:
                for lane in section.lanes:
                    if not np.isfinite(lane.centre_line).all():
                        raise ValueError("non-finite centre line")
                    lanes += 1
        except Exception as exc:  # noqa: BLE001
            failed.append(f"{road.id}: {type(exc).__name__}: {exc}")
    return {"roads": len(roads), "lanes": lanes, "failed": failed}


READERS = {"asam": asam, "commonroad": commonroad, "pyxodr": pyxodr}

if __name__ == "__main__":
    logging.disable(logging.CRITICAL)
    warnings.filterwarnings("ignore")
    reader = READERS[sys.argv[1]]
    for name in sys.argv[2:]:
        print(json.dumps({"file": name, "reader": sys.argv[1], **reader(Path(name).resolve())}), flush=True)
