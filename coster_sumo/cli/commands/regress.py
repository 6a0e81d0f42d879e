"""``coster-sumo regress SOURCES... --planner P [--planner P2 ...]``: planners on the same generated variants."""

from __future__ import annotations

import argparse
from pathlib import Path

from coster_sumo.cli.commands.run import add_avoidability_arguments, add_method_arguments
from coster_sumo.core.spec import GenerationConfig
from coster_sumo.errors import not_found


def add_scene_source_arguments(p: argparse.ArgumentParser, duration: bool = False, several: bool = False) -> None:
    """Scene-source arguments shared with ``eval scenarios`` (``duration``: offer --duration;
    ``several``: --target repeated and --targets N, the targets of a configuration sharing its pass)."""
    p.add_argument("sources", nargs="+", metavar="SOURCE",
                   help="scene sources: CFG.sumocfg[@seed=N,begin=S,end=S,target=ID], a folder (every .sumocfg "
                        "below, e.g. converted WOMD scenes) or a text file listing sources")
    p.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    p.add_argument("--seeds", type=int, default=1, help="scenes per configuration: seeds seed..seed+N-1 (default 1)")
    p.add_argument("--begin", type=float, help="[s] start of every scene's window")
    window = p.add_mutually_exclusive_group()
    window.add_argument("--end", type=float, help="[s] end of every scene's window (default: the configuration's)")
    if duration:
        window.add_argument("--duration", type=float,
                            help="[s] every scene's window from its begin (instead of --end), as in run")
    if several:
        who = p.add_mutually_exclusive_group()
        who.add_argument("--target", action="append",
                         help="target vehicle id (default: the SDC of a converted scene, else 'ego'); repeat it for "
                              "several: the targets of a configuration share one nominal pass")
        who.add_argument("--targets", type=int, metavar="N",
                         help="choose N targets per configuration as run --targets N does (they share its pass)")
    else:
        p.add_argument("--target", help="target vehicle id (default: the SDC of a converted scene, else 'ego')")
    p.add_argument("--workers", type=int, default=1, help="runs at a time, one process each (default 1)")
    p.add_argument("--executor", choices=("local", "ray"), default="local",
                   help="local processes, or a Ray cluster (pip install ray)")
    p.add_argument("--address", "--ray-address", dest="ray_address",
                   help="Ray cluster address HOST:PORT (default: a local Ray instance); its workers need no disk "
                        "shared with OUT")
    p.add_argument("--timeout", type=float, default=900.0,
                   help="[s] wall clock per task; a task past it is killed and marked failed (default 900; 0 = none)")
    p.add_argument("--models", type=Path, help="folder with prior/rollout weights (default: shipped)")


def register(cli) -> None:  # type: ignore[no-untyped-def]
    p = cli.commands.add_parser(
        "regress", help="regression of SUMO planners on generated safety-critical variants",
        description="For every scene the adversary variants are generated once; every planner then drives the "
                    "target on the same variants, each run in its own process with a timeout. Rows go to "
                    "OUT/results/ (Parquet, one part per run; a rerun skips what is done); OUT/summary.json, "
                    "OUT/report.md and OUT/report.html hold RCR / CR / ORR per planner with Wilson 95% intervals.")
    add_scene_source_arguments(p, duration=True, several=True)
    p.add_argument("--planner", action="append", required=True, dest="planners",
                   help="replay | sumo | sumo:<carFollowModel> | module:Class | path/to/file.py:Class; "
                        "repeat for several")
    p.add_argument("--variants", type=int, default=GenerationConfig.variants,
                   help="adversary variants per scene (K-means K, default %(default)s, as in run)")
    p.add_argument("--samples", type=int, default=GenerationConfig.samples,
                   help="CVAE trajectories oversampled (default %(default)s)")
    add_method_arguments(p)
    add_avoidability_arguments(p)
    p.add_argument("--traffic", choices=("log", "reactive"), default="log",
                   help="a converted scene's agents: log (replayed; default) or reactive (each follows its log until "
                        "the target's deviation reaches it, then SUMO drives it; one -o folder per mode)")
    p.add_argument("--retry-failed", action="store_true", help="run again what failed before (default: keep)")
    p.add_argument("--no-report", action="store_true", help="summary.json only (no Markdown/HTML/plots)")
    p.add_argument("-o", "--out", type=Path, default=Path("out/regress"), help="output folder (default out/regress)")
    p.set_defaults(func=run)


def check_sources_exist(sources: list[str]) -> None:
    """A source path that does not exist is the one missing-file line of every command (exit 2)."""
    for s in sources:
        path = Path(s.split("@", 1)[0])
        if not path.exists():
            raise not_found(path, "file or folder")


def run(args: argparse.Namespace) -> int:
    from coster_sumo.batch.regress import RegressOptions, regress, regression_exit_code

    check_sources_exist(args.sources)
    opts = RegressOptions(sources=args.sources, planners=args.planners, out=args.out, variants=args.variants,
                          duration=getattr(args, "duration", None),
                          workers=args.workers, executor=args.executor, timeout=args.timeout or None,
                          seed=args.seed, seeds=args.seeds, begin=args.begin, end=args.end,
                          target=args.target[0] if args.target else None,
                          more_targets=tuple(args.target[1:]) if args.target else (), targets=args.targets,
                          init=args.init, rollout=args.rollout, collision_time=args.collision_time,
                          samples=args.samples, models_dir=args.models, retry_failed=args.retry_failed,
                          adversary=args.adversary,
                          report=not args.no_report, quiet=args.quiet, ray_address=args.ray_address,
                          reaction_time=args.reaction_time, avoidable=args.avoidable, traffic=args.traffic)
    summary = regress(opts)
    # --quiet drops the progress bars and the file list; the tables and every failure line stay
    from coster_sumo.batch.by_class import class_table
    from coster_sumo.batch.report import defect_table, regression_table

    tables = [defect_table(summary), regression_table(summary)]
    if any(c != "vehicle" for per in summary.defects_by_class.values() for c in per):
        tables.insert(1, class_table(summary.defects_by_class))  # the defect rate per adversary class
    for head, rows in tables:
        width = [max([len(h)] + [len(r[i]) for r in rows]) for i, h in enumerate(head)]
        print("  ".join(h.ljust(w) for h, w in zip(head, width, strict=True)))
        for r in rows:
            print("  ".join(c.ljust(w) for c, w in zip(r, width, strict=True)))
    sc, runs = summary.scenes, summary.runs
    if summary.variants_tried != summary.variants:
        print(f"--avoidable only: {summary.variants} avoidable variants of {summary.variants_tried} tried")
    print(f"{sc.generated}/{sc.total} scenes, {runs.recorded}/{runs.expected} runs "
          f"({runs.failed} failed) in {summary.wall_time_s or 0.0:.1f} s"
          + ("" if args.quiet else f"; wrote {args.out}/summary.json"
             + (f", {args.out}/report.html" if not args.no_report else "")))
    for f in sc.failed:
        print(f"  scene failed: {f.scene}: {f.reason}")
    for failure in runs.failures:
        print(f"  run failed: {failure.run_key}: {failure.reason}")
    return regression_exit_code(summary)
