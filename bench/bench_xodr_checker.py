"""ASAM's OpenDRIVE checker, commonroad and pyxodr over many generated scenes (issue 64).

    python bench/bench_xodr_checker.py [--work DIR] [--seed 0] [--per-sample 15] [--per-net 2]
                                       [--only NAME ...] [--readers asam commonroad pyxodr] [--jobs 1]
                                       [--reuse-nets | --reuse] [--names NAME ...] [--clips DIR ...]

Generates the scenes of ``bench/xodr_scenes.py`` (WOMD crops and transforms, cuts of every corpus
network and of extra netgenerate nets, and those cuts converted by the project's converter),
exports each with :func:`coster_sumo.exports.opendrive.write_xodr` into ``WORK/xodr/`` and runs
each reader (``tests/xodr_reader_probe.py`` in the environments ``make xodr-readers`` builds) over
all of them. Prints per reader the totals and every file with a finding, and writes
``WORK/summary.json`` (each reader's rows also go to ``WORK/rows_<reader>.jsonl`` as they come).
``--reuse-nets``: export the nets of an earlier run (``WORK/nets.json``) again;
``--reuse``: check the ``.xodr`` files already in ``WORK/xodr/``;
``--names``: generate only the scenes of these names (the same nets the whole list has);
``--clips``: instead, folders of converted corpus clips (``coster-sumo convert`` of a ``corpus
build``), one clip per network (the first by name) with its converted net as it is.
Exit status 0 when every reader found nothing.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from pathlib import Path

from defusedxml import ElementTree as SafeET

sys.path.insert(0, str(Path(__file__).resolve().parent))
import xodr_scenes  # noqa: E402

from coster_sumo.exports.opendrive import write_xodr  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
PROBE = REPO / "tests" / "xodr_reader_probe.py"
ENVS = {"asam": ".venv-xodr-asam", "commonroad": ".venv-xodr-readers", "pyxodr": ".venv-xodr-readers"}
CHUNK = 20  # files per reader process (memory stays bounded)
VERSION_SKIPPED = {"check_asam_xodr_junctions_connection_one_connection_element"}  # OpenDRIVE <= 1.7 only


def generate(work: Path, args: argparse.Namespace) -> list[dict]:
    """Generate every scene's SUMO net; records them in ``WORK/nets.json`` (name, family, net)."""
    nets = []
    names = set(args.names) if args.names else None
    for test in xodr_scenes.all_nets(work, args.seed, args.per_sample, args.per_net, only=args.only, names=names):
        nets.append({"name": test.name, "family": test.family, "net": str(test.net)})
        print(f"generated {test.name} ({test.family})", flush=True)
        (work / "nets.json").write_text(json.dumps(nets, indent=1))
    return nets


def corpus_clips(folders: list[Path]) -> list[dict]:
    """One converted clip per network of each folder (clip folders ``<network>_r<run>_...``, the
    first by name), as scenes of family ``corpus-clip``; recorded like :func:`generate`'s."""
    first: dict[str, Path] = {}
    for folder in folders:
        for clip in sorted(p for p in folder.iterdir() if p.is_dir()):
            network = re.sub(r"_r\d+_.*$", "", clip.name)
            nets = sorted(clip.glob("*.net.xml"))
            if nets and network not in first:
                first[network] = nets[0]
    return [{"name": f"clip_{net.parent.name}", "family": "corpus-clip", "net": str(net)}
            for _, net in sorted(first.items())]


def export_one(name: str, net: str, out: Path) -> tuple[str, str, float]:
    """Export one net to ``out/<name>.xodr``: (name, the error or "", seconds)."""
    t0 = time.perf_counter()
    try:
        write_xodr(Path(net), out / f"{name}.xodr")
    except Exception as exc:  # noqa: BLE001 - a failed export is a finding
        return name, f"{type(exc).__name__}: {exc}", time.perf_counter() - t0
    return name, "", time.perf_counter() - t0


def export_all(work: Path, nets: list[dict], jobs: int = 1) -> list[str]:
    """Export every net into ``WORK/xodr/`` (``jobs`` processes); returns the scenes whose export failed."""
    out = work / "xodr"
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    failed = []
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        for name, error, secs in pool.map(export_one, [n["name"] for n in nets], [n["net"] for n in nets],
                                          [out] * len(nets)):
            if error:
                failed.append(f"{name}: {error}")
            print(f"exported {name} in {secs:.1f} s{' FAILED ' + error if error else ''}", flush=True)
    return failed


def probe(reader: str, files: list[Path], jobs: int = 1, log: Path | None = None) -> dict[str, dict]:
    """Run one reader over ``files`` in chunks of :data:`CHUNK`, ``jobs`` reader processes at a time;
    each chunk's rows are appended to ``log`` (JSON lines) as it finishes."""
    python = REPO / ENVS[reader] / "bin" / "python"
    if not python.is_file():
        raise SystemExit(f"{python} not found: run `make xodr-readers`")

    def run(chunk: list[Path]) -> str:
        proc = subprocess.run([str(python), str(PROBE), reader, *map(str, chunk)],
                              capture_output=True, text=True, timeout=7200)
        if proc.returncode != 0:
            raise SystemExit(f"{reader} probe failed: {proc.stderr[-2000:]}")
        return proc.stdout

    chunks = [files[k:k + CHUNK] for k in range(0, len(files), CHUNK)]
    rows: dict[str, dict] = {}
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        for out in pool.map(run, chunks):
            for line in out.splitlines():
                if line.startswith("{"):
                    row = json.loads(line)
                    rows[Path(row["file"]).stem] = row
                    if log is not None:
                        with log.open("a") as fh:
                            fh.write(line + "\n")
    return rows


def findings(reader: str, row: dict, path: Path) -> dict:
    """What a reader found wrong in one file (empty: nothing)."""
    if "error" in row:
        return {"error": row["error"]}
    if reader == "asam":
        out: dict = {}
        for cid, ch in row["checkers"].items():
            if ch["issues"]:
                out[cid] = ch["issues"]
            if ch["status"] != ("skipped" if cid in VERSION_SKIPPED else "completed"):
                out[f"{cid}:status"] = ch["status"]
        return out
    if reader == "commonroad":
        return {"invalid": row["invalid"]} if row["invalid"] or row["lanelets"] == 0 else {}
    roads = len(SafeET.parse(str(path)).getroot().findall("road"))
    return {"failed": row["failed"]} if row["failed"] or row["roads"] != roads else {}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--per-sample", type=int, default=15)
    ap.add_argument("--per-net", type=int, default=2)
    ap.add_argument("--only", nargs="*", default=None, help="'womd' and/or source net names")
    ap.add_argument("--names", nargs="*", default=None, help="only the scenes of these names")
    ap.add_argument("--clips", nargs="*", type=Path, default=None,
                    help="folders of converted corpus clips: one clip per network instead of generated scenes")
    ap.add_argument("--readers", nargs="*", default=list(ENVS), choices=list(ENVS))
    ap.add_argument("--jobs", type=int, default=1, help="export and reader processes at a time")
    ap.add_argument("--reuse-nets", action="store_true", help="export the nets WORK/nets.json lists again")
    ap.add_argument("--reuse", action="store_true", help="check the .xodr files in WORK/xodr/ as they are")
    args = ap.parse_args()
    work = args.work or xodr_scenes.scratch()
    t0 = time.perf_counter()
    if args.reuse_nets or args.reuse:
        nets = json.loads((work / "nets.json").read_text())
    elif args.clips:
        nets = corpus_clips(args.clips)
        work.mkdir(parents=True, exist_ok=True)
        (work / "nets.json").write_text(json.dumps(nets, indent=1))
    else:
        nets = generate(work, args)
    failed = [] if args.reuse else export_all(work, nets, args.jobs)
    families = {n["name"]: n["family"] for n in nets}
    files = sorted((work / "xodr").glob("*.xodr"))
    summary: dict = {"scenes": len(files), "export_failed": failed, "export_s": round(time.perf_counter() - t0, 1),
                     "families": families, "readers": {}}
    print(f"{len(files)} exported scenes in {work / 'xodr'}; {len(failed)} exports failed", flush=True)
    for line in failed:
        print(f"  export failed: {line}")
    ok = not failed
    for reader in args.readers:
        t1 = time.perf_counter()
        log = work / f"rows_{reader}.jsonl"
        log.unlink(missing_ok=True)
        rows = probe(reader, files, args.jobs, log)
        bad = {name: f for name in sorted(rows) if (f := findings(reader, rows[name], work / "xodr" / f"{name}.xodr"))}
        missing = sorted({p.stem for p in files} - set(rows))
        totals: dict[str, int] = {}
        for f in bad.values():
            for key, val in f.items():
                n = sum(val.values()) if isinstance(val, dict) else (len(val) if isinstance(val, list) else 1)
                totals[key] = totals.get(key, 0) + n
        if reader == "commonroad":
            summary["lanelets"] = sum(r.get("lanelets", 0) for r in rows.values())
        summary["readers"][reader] = {"files": len(rows), "files_with_findings": len(bad), "totals": totals,
                                      "missing": missing, "bad": bad, "s": round(time.perf_counter() - t1, 1)}
        print(f"{reader}: {len(rows)} files read, {len(bad)} with findings, totals {totals}, "
              f"{len(missing)} missing ({time.perf_counter() - t1:.0f} s)", flush=True)
        for name, f in bad.items():
            print(f"  {name}: {f}")
        ok = ok and not bad and not missing
    (work / "summary.json").write_text(json.dumps(summary, indent=1))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
