"""``coster-sumo convert INPUT... -o OUTDIR``: WOMD scenes -> converted SUMO scene folders.

Every record of every input (WOMD TFRecord, gzip TFRecord, ScenarioNet pickle, our ``.npz``)
becomes ``OUTDIR/<name>/`` (see :mod:`coster_sumo.converters.to_sumo`), where ``name`` is the scenario
id when it is a safe folder name and a sanitised one otherwise
(:func:`coster_sumo.formats.scene_folder.folder_name`; a name already used in this run gets ``-2``,
``-3``, ...). A bad input or record prints one line naming the file and record and the rest go on.
``OUTDIR/summary.json`` lists every scene with its fidelity figures and folder name, every failure,
and ``renamed``: folder name -> scenario id wherever they differ. Exit code 0: all converted; 1: some
failed; 2: usage error or nothing could be read (then nothing is written: OUTDIR is not created,
or left as it was).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from coster_sumo.errors import CosterError, not_found, one_line
from coster_sumo.infra.atomic import write_json
from coster_sumo.infra.outdir import MARKER, OutputLock, check_output, clean_leftovers_in, write_marker


def register(cli) -> None:  # type: ignore[no-untyped-def]
    p = cli.commands.add_parser(
        "convert", help="convert WOMD scenes (TFRecord / ScenarioNet pickle) into SUMO scenes",
        description="Each scene becomes OUTDIR/<scenario_id>/ with <id>.net.xml, <id>.rou.xml, "
                    "<id>.sumocfg, scene.npz, lane_map.json and summary.json (fidelity figures).")
    p.add_argument("inputs", nargs="+", type=Path, metavar="INPUT",
                   help="WOMD Scenario TFRecord (plain or gzip), ScenarioNet .pkl or scene .npz")
    p.add_argument("-o", "--out", type=Path, required=True, metavar="OUTDIR",
                   help="output folder: new, empty, or an earlier convert output (scenes are added to it)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace a scene folder of the same name that an earlier convert wrote (default: such a "
                        "scene fails with one line and the others go on)")
    p.set_defaults(func=run)


def _fmt(v: float | None, unit: str = "", digits: int = 3) -> str:
    return "n/a" if v is None else f"{v:.{digits}f}{unit}"


def fidelity_line(summary: dict) -> str:
    """One line of per-scene fidelity figures."""
    f = summary["fidelity"]
    return (f"{summary['scenario_id']}: lanes matched {f['lanes_matched']}/{f['lanes']} "
            f"({100 * f['lanes_matched_share']:.1f}%), links realised {f['links_realised']}/{f['links']} "
            f"({100 * f['links_realised_share']:.1f}%), centreline mean {_fmt(f['centreline_mean_m'], ' m', 4)} "
            f"max {_fmt(f['centreline_max_m'], ' m', 4)}{_continuity(f)}, {summary['conversion_s']:.2f} s")


def _continuity(fidelity: dict) -> str:
    """How the net's lanes join at its connections (absent in summaries of older conversions)."""
    c = fidelity.get("continuity")
    if not c:
        return ""
    return (f", joints apart > {c['tolerance_m']:g} m {c['joints_over_tolerance']}/{c['joints']} "
            f"(max gap {c['max_gap_m']:.3f} m, max kink {c['max_kink_deg']:.1f} deg, "
            f"junction curvature max {c['max_internal_curvature_per_m']:.2f} 1/m)")


def run(args: argparse.Namespace) -> int:
    debug = bool(getattr(args, "debug", False))
    quiet = bool(getattr(args, "quiet", False))
    out: Path = args.out
    missing = [p for p in args.inputs if not p.exists()]
    if len(missing) == len(args.inputs):  # nothing to read: the one missing-file line, before any work
        raise not_found(missing[0])
    check_output(out, kind="convert", inputs=args.inputs, reusable=True)
    with OutputLock(out):
        if out.is_dir():
            clean_leftovers_in(out)  # staging folders of a convert that was stopped
        return _convert_locked(args, out, debug, quiet)


@dataclass
class _Batch:
    """One ``convert`` call's progress: the folder names handed out (``renamed``: name -> scenario id
    where they differ), the scenes written and the failures, each failure also printed as one line."""

    out: Path
    debug: bool
    quiet: bool
    overwrite: bool
    bar: Any  # a tqdm bar over the scenes written
    used: set[str] = field(default_factory=set)
    renamed: dict[str, str] = field(default_factory=dict)
    scenes: list[dict] = field(default_factory=list)
    failures: list[dict] = field(default_factory=list)
    read_any: bool = False

    def fail(self, where: str, message: str, path: Path) -> None:
        from tqdm import tqdm

        # readers name the file themselves; say it once, followed by the record
        if not message.startswith(where) and message.startswith(f"{path}: "):
            message = message[len(f"{path}: "):]
        line = one_line(message if message.startswith(where) else f"{where}: {message}")
        self.failures.append({"where": one_line(where), "error": line})
        tqdm.write(f"coster-sumo: error: {line}", file=sys.stderr)

    def name_for(self, sid: str) -> str:
        from coster_sumo.formats.scene_folder import MAX_FOLDER_NAME, folder_name

        base = folder_name(sid)
        name, k = base, 1
        while name in self.used:  # a name taken earlier in this run: -2, -3, ... (still a safe name)
            k += 1
            name = f"{base[:MAX_FOLDER_NAME - len(str(k)) - 1]}-{k}"
        self.used.add(name)
        if name != sid:
            self.renamed[name] = sid
        return name

    def release(self, name: str) -> None:  # the scene failed: its name is free again
        self.used.discard(name)
        self.renamed.pop(name, None)

    def convert_file(self, path: Path) -> None:
        """Every record of ``path``; a reader error ends the file (said as one line), not the batch."""
        from coster_sumo.converters.read import iter_scenes

        record = 0
        try:
            for scene in iter_scenes(path):
                self.read_any = True
                record += 1  # counted first: an error after this record names the next one
                self.convert_record(scene, path, record - 1)
        except CosterError as exc:
            if self.debug:
                raise
            self.fail(f"{path}: record {record}", str(exc), path)
        except Exception as exc:  # a reader bug on one file must not stop the others
            if self.debug:
                raise
            self.fail(f"{path}: record {record}", f"{type(exc).__name__}: {' '.join(str(exc).split())}", path)

    def convert_record(self, scene: Any, path: Path, record: int) -> None:
        """Convert one scene read from ``path``; a failure is one line and frees its folder name."""
        from tqdm import tqdm

        from coster_sumo.converters.to_sumo import convert_scene

        sid = str(scene.scenario_id)
        where = f"{path}: record {record} ({one_line(sid[:60])}{'...' if len(sid) > 60 else ''})"
        name = self.name_for(sid)
        try:
            self.out.mkdir(parents=True, exist_ok=True)
            result = convert_scene(scene, self.out, name=name, overwrite=self.overwrite)
        except CosterError as exc:
            if self.debug:
                raise
            self.release(name)
            self.fail(where, str(exc), path)
            return
        except Exception as exc:  # one bad scene must not stop the batch
            if self.debug:
                raise
            self.release(name)
            self.fail(where, f"{type(exc).__name__}: {' '.join(str(exc).split())}", path)
            return
        self.scenes.append({"input": str(path), "record": record, "folder": str(result.folder),
                            **{k: result.summary[k] for k in ("scenario_id", "fidelity", "conversion_s")},
                            "warnings": len(result.summary["warnings"])})
        if not self.quiet:
            tqdm.write(fidelity_line(result.summary))
        self.bar.update(1)


def _convert_locked(args: argparse.Namespace, out: Path, debug: bool, quiet: bool) -> int:
    """:func:`run` once OUTDIR is checked and locked."""
    from tqdm import tqdm

    created = not out.exists()
    t0 = time.perf_counter()
    bar = tqdm(desc="convert", unit="scene", disable=quiet, file=sys.stderr, dynamic_ncols=True)
    batch = _Batch(out, debug, quiet, bool(getattr(args, "overwrite", False)), bar)
    for path in args.inputs:
        if not path.exists():
            batch.failures.append({"where": one_line(str(path)), "error": one_line(str(not_found(path)))})
            tqdm.write(f"coster-sumo: error: {batch.failures[-1]['error']}", file=sys.stderr)
            continue
        batch.convert_file(path)
    bar.close()
    if not batch.scenes and not batch.read_any:  # nothing could be read: write nothing
        if created and out.is_dir() and not any(out.iterdir()):
            out.rmdir()
        print(f"converted 0 scene(s), {len(batch.failures)} failed; nothing written")  # --quiet too: the result
        return 2
    out.mkdir(parents=True, exist_ok=True)
    summary = {"outdir": str(out), "inputs": [str(p) for p in args.inputs], "converted": len(batch.scenes),
               "failed": len(batch.failures), "scenes": batch.scenes, "failures": batch.failures,
               "renamed": batch.renamed, "wall_s": round(time.perf_counter() - t0, 3)}
    write_json(out / "summary.json", summary)
    if not (out / MARKER).exists():
        write_marker(out, "convert")
    print(f"converted {len(batch.scenes)} scene(s) into {out}, {len(batch.failures)} failed")  # --quiet too
    return 1 if batch.failures else 0
