"""Benchmark: generation time per variant on held-out clips, this tree against a git ref, in one run.

What is timed is what ``coster-sumo eval scenarios`` reports as "gen. s/variant": in a task process
forked from a server that has imported the task modules (the eval driver's fork), the call
:func:`coster_sumo.method.generation.generate_variants` for COSTER (snapshot init, entropy collision time, CVAE,
``--variants`` 5, ``--samples`` 1000) on one scene, divided by the variants it returns. Every cost
that falls inside that call in a fresh task (imports of torch and scikit-learn, loading weights,
the prior, the CVAE, clustering) is counted, as in the eval.

Two recipes, each in its own server process: **baseline** = the package as of ``--baseline-ref``
(extracted from git into a temporary folder and put first on ``sys.path``), **current** = this
working tree. Scenes alternate between them (baseline first on even scenes, current first on odd
ones) so that the load of a shared machine falls on both alike; every scene is one task at a time
with ``--threads`` torch threads (1: what each of two eval workers on two cores gets). Both use
the same weights (``--models``, default the shipped ``models/`` of this tree).

Output: per scene the two times and whether the variants are the same (same number, same
collision time and adversary state, plan knots within ``--tolerance`` metres / radians); then the
per-variant times as the eval aggregates them (mean over scenes of time / variants) in wall and in
the task's CPU time (one torch thread: on a loaded machine the CPU time is what the call costs, the
wall time what it waited as well), the median
per-scene ratio baseline / current, and the load average. ``--warm`` also times a second call in
the same task (weights and imports already there: the cost inside a long-lived process).

Usage:
    python bench/bench_generation.py CLIPS [--scenes 20] [--baseline-ref REF] [--threads 1]
                                           [--warm] [--json OUT.json]

CLIPS: a folder of scene ``.npz`` files (e.g. ``CORPUS/heldout`` of ``coster-sumo corpus build``,
file names ``<network>_r<run>_...``); ``--scenes`` of them are taken spread evenly over each
network's sorted list.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
BASELINE_REF = "657c963"  # main before issue 47's generation work

# The server: imports what the eval driver has imported when it forks a task, then for every
# request line forks a task that times generate_variants and writes one JSON line back.
SERVER = r'''
import importlib, json, os, sys, time
sys.path.insert(0, sys.argv[1])
import libsumo, pyarrow.parquet  # noqa: F401
import coster_sumo


def have(module):
    # asked of the files: an editable install of the current tree would answer a module the tree
    # asked for does not hold from the current tree
    path = os.path.join(sys.argv[1], *module.split("."))
    return os.path.isfile(path + ".py") or os.path.isfile(os.path.join(path, "__init__.py"))


def pick(name, *modules):
    # the name from the first of ``modules`` the tree holds (the package's layout moved over time)
    for module in modules:
        if have(module):
            return getattr(importlib.import_module(module), name)
    raise ImportError(f"{name}: none of {modules} in {sys.argv[1]}")


for module in ("coster_sumo.batch.evaluate", "coster_sumo.pipeline.outputs", "coster_sumo.outputs",
               "coster_sumo.sim.inject"):
    if have(module):
        importlib.import_module(module)
generate_variants = pick("generate_variants", "coster_sumo.method.generation", "coster_sumo.core")
choose_target = pick("choose_target", "coster_sumo.formats.targets", "coster_sumo.pipeline.scenario",
                     "coster_sumo.core")
load_scene = pick("load_scene", "coster_sumo.formats.scene_file", "coster_sumo.core.scene", "coster_sumo.scene")
DrivableArea = pick("DrivableArea", "coster_sumo.geometry.drivable", "coster_sumo.drivable")
GenerationConfig = pick("GenerationConfig", "coster_sumo.core.spec", "coster_sumo.spec")
from coster_sumo.batch import executor
preload = getattr(executor, "GENERATION_TASK_MODULES", ())
for name in preload:
    __import__(name)
print(json.dumps({"ready": coster_sumo.__file__, "preload": list(preload)}), flush=True)
for line in sys.stdin:
    req = json.loads(line)
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.close(r)
        executor._limit_threads(req["threads"])
        out = {}
        try:
            from pathlib import Path
            scene = load_scene(req["scene"])
            target = choose_target(scene, None, req["scene"])
            drivable = DrivableArea.from_road_map(scene.road_map)
            gen = GenerationConfig(init="snapshot", rollout="cvae", collision_time="entropy",
                                   variants=req["variants"], samples=req["samples"],
                                   models_dir=Path(req["models"]))
            times, cpu = [], []
            for _ in range(2 if req["warm"] else 1):
                t0, c0 = time.perf_counter(), time.process_time()
                try:
                    variants, _ = generate_variants(scene, target, req["seed"], gen, drivable)
                except Exception as exc:  # NoSnapshot: a scene without a scenario, timed all the same
                    variants, out["error"] = [], f"{type(exc).__name__}: {exc}"
                times.append(time.perf_counter() - t0)
                cpu.append(time.process_time() - c0)
            out.update(times=times, cpu=cpu, variants=[v.to_dict() for v in variants])
        except BaseException as exc:
            out = {"error": f"{type(exc).__name__}: {exc}", "times": [], "cpu": [], "variants": []}
        with os.fdopen(w, "w") as fh:
            fh.write(json.dumps(out))
        os._exit(0)
    os.close(w)
    with os.fdopen(r) as fh:
        text = fh.read()
    os.waitpid(pid, 0)
    print(text, flush=True)
'''


def extract_ref(ref: str, dest: Path, extra: tuple[tuple[str, str], ...] = ()) -> Path:
    """The package of git ``ref`` laid out as it installs (converters/ inside coster_sumo/) in ``dest``;
    ``extra``: more (repository folder, place in ``dest``) pairs, e.g. the package data."""
    for folder, inside in (("coster_sumo", "coster_sumo"), ("converters", "coster_sumo/converters"), *extra):
        blob = subprocess.run(["git", "archive", "--format=tar", ref, folder], cwd=REPO, check=True,
                              capture_output=True).stdout
        with tarfile.open(fileobj=BytesIO(blob)) as tar:
            for m in tar.getmembers():
                m.name = inside + m.name[len(folder):]
                tar.extract(m, dest, filter="data")
    return dest


class Server:
    """One recipe's server process."""

    def __init__(self, name: str, root: Path) -> None:
        self.name = name
        env = {**os.environ, "PYTHONWARNINGS": "ignore"}
        self.proc = subprocess.Popen([sys.executable, "-c", SERVER, str(root)], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, text=True, env=env, cwd=tempfile.gettempdir())
        self.ready = self._read()

    def _read(self) -> dict[str, Any]:
        assert self.proc.stdout is not None
        while True:
            line = self.proc.stdout.readline()
            if not line:
                raise RuntimeError(f"{self.name} server stopped")
            if line.startswith("{"):
                return json.loads(line)  # type: ignore[no-any-return]

    def task(self, req: dict[str, Any]) -> dict[str, Any]:
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps(req) + "\n")
        self.proc.stdin.flush()
        return self._read()

    def close(self) -> None:
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        self.proc.wait()


def pick_scenes(clips: Path, count: int) -> list[Path]:
    """``count`` scene files spread evenly over each network's sorted list (networks by file-name prefix)."""
    files = sorted(clips.glob("*.npz"))
    by_net: dict[str, list[Path]] = {}
    for f in files:
        by_net.setdefault(f.name.split("_r")[0], []).append(f)
    nets = sorted(by_net)
    per = [count // len(nets) + (i < count % len(nets)) for i in range(len(nets))]
    out = []
    for net, k in zip(nets, per, strict=True):
        lst = by_net[net]
        out += [lst[int((j + 0.5) * len(lst) / k)] for j in range(k)] if k else []
    return out


def compare(a: list[dict[str, Any]], b: list[dict[str, Any]]) -> float:
    """Largest difference between two variant lists' plan knots and adversary states [m, rad, m/s];
    inf when their number, ids or collision times differ."""
    if len(a) != len(b):
        return float("inf")
    worst = 0.0
    for va, vb in zip(a, b, strict=True):
        pa, pb = va["plan"], vb["plan"]
        if pa["vehicle_id"] != pb["vehicle_id"] or va["snapshot"]["t_index"] != vb["snapshot"]["t_index"]:
            return float("inf")
        for key in ("times", "x", "y", "yaw", "length", "width", "final_speed"):
            xa, xb = (v if isinstance(v, list) else [v] for v in (pa[key], pb[key]))
            if len(xa) != len(xb):
                return float("inf")
            worst = max([worst, *(abs(p - q) for p, q in zip(xa, xb, strict=True))])
        sa, sb = va["snapshot"]["adversary"], vb["snapshot"]["adversary"]
        worst = max([worst, *(abs(float(sa[k]) - float(sb[k])) for k in sa)])
    return worst


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("clips", type=Path, help="folder of held-out scene .npz files")
    ap.add_argument("--scenes", type=int, default=20)
    ap.add_argument("--baseline-ref", default=BASELINE_REF)
    ap.add_argument("--threads", type=int, default=1, help="torch threads per task (%(default)s)")
    ap.add_argument("--variants", type=int, default=5)
    ap.add_argument("--samples", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--models", type=Path, default=REPO / "models")
    ap.add_argument("--tolerance", type=float, default=1e-4, help="[m, rad] plan knots count as the same")
    ap.add_argument("--warm", action="store_true", help="also time a second call in the same task")
    ap.add_argument("--json", type=Path, help="write every measurement here")
    args = ap.parse_args()
    scenes = pick_scenes(args.clips, args.scenes)
    with tempfile.TemporaryDirectory(prefix="bench-gen-") as tmp:
        base = Server("baseline", extract_ref(args.baseline_ref, Path(tmp)))
        cur = Server("current", REPO)
        print(f"baseline {args.baseline_ref}: {base.ready['ready']}\ncurrent: {cur.ready['ready']} "
              f"(preloaded {cur.ready['preload'] or 'nothing more'})")
        load0 = os.getloadavg()
        rows = []
        for i, scene in enumerate(scenes):
            req = {"scene": str(scene), "seed": args.seed, "variants": args.variants, "samples": args.samples,
                   "threads": args.threads, "models": str(args.models.resolve()), "warm": args.warm}
            order = (base, cur) if i % 2 == 0 else (cur, base)
            got = {s.name: s.task(req) for s in order}
            b, c = got["baseline"], got["current"]
            diff = compare(b["variants"], c["variants"])
            row = {"scene": scene.name, "variants": len(c["variants"]), "baseline_s": b["times"],
                   "current_s": c["times"], "baseline_cpu_s": b["cpu"], "current_cpu_s": c["cpu"],
                   "max_diff": diff, "same": diff <= args.tolerance,
                   "errors": [x.get("error") for x in (b, c) if x.get("error")]}
            rows.append(row)
            warm = (f", warm {b['times'][1]:.3f} / {c['times'][1]:.3f} s" if args.warm and b["times"]
                    and c["times"] else "")
            print(f"{scene.name}: {len(b['variants'])} / {len(c['variants'])} variants, baseline "
                  f"{b['times'][0] if b['times'] else float('nan'):.3f} s, current "
                  f"{c['times'][0] if c['times'] else float('nan'):.3f} s{warm}; max difference {diff:.2g}"
                  + (f" ({'; '.join(row['errors'])})" if row["errors"] else ""), flush=True)
        load1 = os.getloadavg()
        base.close()
        cur.close()
    ok = [r for r in rows if r["variants"] and r["baseline_s"] and r["current_s"]]

    def per_variant(key: str, which: int = 0) -> float:
        return statistics.mean(r[key][which] / r["variants"] for r in ok)

    ratios = [r["baseline_s"][0] / r["current_s"][0] for r in ok]
    same = sum(r["same"] for r in rows)
    print(f"\n{len(rows)} scenes, {len(ok)} with variants; same variants in {same} of {len(rows)} "
          f"(tolerance {args.tolerance:g}; largest difference {max((r['max_diff'] for r in rows), default=0):.2g})")
    print(f"per variant (mean over scenes of time / variants, as eval reports it): baseline "
          f"{per_variant('baseline_s'):.3f} s, current {per_variant('current_s'):.3f} s")
    print(f"per variant in CPU time of the task (what load does not inflate): baseline "
          f"{per_variant('baseline_cpu_s'):.3f} s, current {per_variant('current_cpu_s'):.3f} s")
    if args.warm:
        print(f"warm (second call in the task): baseline {per_variant('baseline_s', 1):.3f} s, current "
              f"{per_variant('current_s', 1):.3f} s")
    print(f"per-scene ratio baseline / current: median {statistics.median(ratios):.2f} "
          f"(min {min(ratios):.2f}, max {max(ratios):.2f}); torch threads {args.threads}; load average "
          f"{load0[0]:.1f} at the start, {load1[0]:.1f} at the end; {time.strftime('%Y-%m-%d %H:%M')}")
    if args.json:
        args.json.write_text(json.dumps({"args": {k: str(v) for k, v in vars(args).items()}, "rows": rows,
                                         "load": [load0, load1]}, indent=1))


if __name__ == "__main__":
    main()
