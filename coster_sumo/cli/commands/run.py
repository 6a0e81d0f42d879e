"""``coster-sumo run CFG``: generate safety-critical variants for a target and play them in SUMO."""

from __future__ import annotations

import argparse
import contextlib
import functools
import sys
import time
from pathlib import Path
from typing import Any

from coster_sumo.core.results import RunResult, RunSummary, TargetEntry, TargetResult, VariantOutcome
from coster_sumo.core.spec import ADVERSARY_CHOICES, GenerationConfig, ScenarioSpec
from coster_sumo.errors import CosterError, InputError
from coster_sumo.formats.sumocfg import read_sumocfg
from coster_sumo.infra import procs, progress
from coster_sumo.infra.progress import Bars
from coster_sumo.method.collision_time import COLLISION_TIME_RULES
from coster_sumo.method.snapshot import SNAPSHOT_INITS
from coster_sumo.pipeline.run import RunOptions
from coster_sumo.pipeline.run import run as run_scenario
from coster_sumo.rollout.methods import ROLLOUTS


def register(cli) -> None:  # type: ignore[no-untyped-def]
    p = cli.commands.add_parser(
        "run", help="generate adversaries for a target and inject them into a SUMO configuration",
        description="Nominal pass, collision snapshot, backward rollout, one injection pass per variant. "
                    "Writes summary.json, events.jsonl, collisions.xml, trajectories, renders and "
                    "standalone exports into OUTDIR.")
    p.add_argument("config", type=Path, metavar="CFG",
                   help=".sumocfg (a converted WOMD scene or any SUMO configuration)")
    who = p.add_mutually_exclusive_group()
    who.add_argument("--target", action="append",
                     help="target vehicle id (default: the SDC of a converted scene, else 'ego'); repeat it for "
                          "several targets sharing one nominal pass (outputs in OUT/<target>/)")
    who.add_argument("--targets", type=int, metavar="N",
                     help="choose N targets: the vehicles of the demand expected to run longest in the window "
                          "(free-flow time of their routes; a converted scene: the longest in its log); the "
                          "choice is printed and kept in OUT/summary.json")
    p.add_argument("--planner", help="replay | sumo | sumo:<carFollowModel> | module:Class (a module on the "
                                     "import path or in the working directory) | path/to/file.py:Class "
                                     "(default: replay for converted scenes, sumo otherwise)")
    p.add_argument("--traffic", choices=("log", "reactive"), default="log",
                   help="a converted scene's agents: log (replayed; default) or reactive (each follows its log until "
                        "the target's deviation reaches it, then SUMO drives it); a SUMO configuration's traffic "
                        "runs in SUMO either way")
    p.add_argument("--samples", type=int, default=1000, help="trajectories oversampled (default 1000)")
    p.add_argument("--variants", type=int, default=5, help="representatives kept (K-means K, default 5)")
    add_method_arguments(p)
    p.add_argument("--begin", type=float, help="[s] simulation begin, absolute like SUMO's -b (default: the "
                                                "configuration's)")
    window = p.add_mutually_exclusive_group()
    window.add_argument("--end", type=float, help="[s] simulation end, absolute like SUMO's -e (default: the "
                                                  "configuration's, else begin + 60)")
    window.add_argument("--duration", type=float, help="[s] simulation length from the begin (instead of --end)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--snapshots", type=int, default=1,
                   help="collision snapshots from the one nominal pass: the K best collision times (2 s apart), "
                        "each with its variants (default 1)")
    p.add_argument("--from-begin", action="store_true",
                   help="simulate every variant from the begin instead of continuing a held copy of the nominal "
                        "pass (same outcome, slower; TraCI always does this)")
    p.add_argument("--traci", action="store_true", help="use a TraCI socket instead of libsumo")
    add_avoidability_arguments(p)
    p.add_argument("--no-render", action="store_true", help="skip the PNG renders")
    add_export_argument(p)
    p.add_argument("--models", type=Path, help="folder with prior/rollout/vocab weights (default: shipped)")
    p.add_argument("--timeout", type=float, metavar="S",
                   help="[s] wall clock per variant's injection pass; a variant past it is stopped and reported "
                        "(default: no limit)")
    p.add_argument("--copy-outside", action="store_true",
                   help="copy into the exports also the files the configuration names outside its own folder "
                        "(default: they are named by absolute path, listed in variant.json, never copied)")
    add_output_arguments(p, "out/run")
    p.set_defaults(func=run)


def add_output_arguments(p: argparse.ArgumentParser, default: str) -> None:
    """-o/--out and --overwrite of the commands that write a run folder (run, demo)."""
    p.add_argument("-o", "--out", type=Path, default=Path(default),
                   help=f"output folder (default {default}): new or empty, or an earlier run output with "
                        "--overwrite")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an earlier coster-sumo run output in OUT (it is replaced only once the new one "
                        "is complete); a folder holding anything else is never replaced")


def add_export_argument(p: argparse.ArgumentParser) -> None:
    """--export: the formats written per variant besides the standalone SUMO folder."""
    p.add_argument("--export", choices=("sumo", "openscenario", "all"), default="sumo",
                   help="sumo (default) = the standalone SUMO folder only; openscenario / all = also "
                        "variants/<i>/openscenario/ as `coster-sumo export` writes it (needs the extra "
                        "coster-sumo[openscenario])")


def add_method_arguments(p: argparse.ArgumentParser) -> None:
    """--init, --collision-time and --rollout, with the choices of their registries."""
    p.add_argument("--collision-time", default="entropy", choices=tuple(COLLISION_TIME_RULES),
                   help="entropy = highest velocity entropy (COSTER); last / random = ablations")
    p.add_argument("--init", default="snapshot", choices=tuple(SNAPSHOT_INITS),
                   help="snapshot = the prior's placement; random = random pose offset baseline")
    p.add_argument("--rollout", default="cvae", choices=tuple(ROLLOUTS),
                   help="cvae = time-reversed CVAE; cv = constant-velocity baseline")
    p.add_argument("--adversary", default="vehicle", choices=ADVERSARY_CHOICES,
                   help="the adversary's class: vehicle (default), cyclist or pedestrian (their own placement; "
                        "the class's learned rollout, models/rollout_CLASS.pt, with --rollout cvae, else its kinematic "
                        "one; injected as SUMO bicycle / pedestrian), or any (each draw picks one)")


def add_avoidability_arguments(p: argparse.ArgumentParser) -> None:
    """--reaction-time and --avoidable (coster_sumo.avoidability.labels)."""
    p.add_argument("--reaction-time", type=float, default=1.0, metavar="S",
                   help="[s] reaction time after the adversary becomes a threat that each variant's avoidable / "
                        "unavoidable label is stated for (default 1.0; 0.5 and 1.5 are reported too)")
    p.add_argument("--avoidable", choices=("any", "only"), default="any",
                   help="any (default) = keep every variant; only = keep the variants the target could have "
                        "avoided (escape proven in SUMO), drawing more to replace the others")


def generation_config(args: argparse.Namespace) -> GenerationConfig:
    """The generation config of parsed arguments (``--init``, ``--samples``, ``--models``...)."""
    return GenerationConfig(init=args.init, collision_time=args.collision_time, rollout=args.rollout,
                            samples=args.samples, variants=args.variants, models_dir=args.models,
                            adversary=getattr(args, "adversary", "vehicle"))


def end_of(args: argparse.Namespace) -> float | None:
    """``--end``, or the begin plus ``--duration`` (the begin: ``--begin``, else the configuration's)."""
    if getattr(args, "duration", None) is None:
        return args.end
    if args.duration <= 0:
        raise InputError(f"--duration must be positive, not {args.duration:g}")
    begin = args.begin if args.begin is not None else (read_sumocfg(args.config).begin or 0.0)
    return begin + args.duration


def run(args: argparse.Namespace) -> int:
    export = getattr(args, "export", "sumo")
    if export != "sumo":  # a missing extra fails before any simulation
        from coster_sumo.exports.openscenario import require_extra

        require_extra()
    targets = args.target or [None]  # RunOptions drops repeats
    end = end_of(args)
    chosen: list[dict[str, Any]] = []
    lines: list[str] = []
    failed: list[tuple[str, dict[str, Any]]] = []
    if getattr(args, "targets", None) is not None:
        from coster_sumo.formats.targets import choose_targets, iter_lines

        picked = choose_targets(args.config, args.targets, args.begin, end)
        targets = [c.vehicle_id for c in picked]
        chosen = [c.to_dict() for c in picked]
        print("\n".join(iter_lines(picked)), flush=True)  # before the long part: the user sees who
    spec = ScenarioSpec(args.config, seed=args.seed, begin=args.begin, end=end, target=targets[0])
    opts = RunOptions(spec=spec, out=args.out, generation=generation_config(args), planner=args.planner,
                      traci=args.traci, render=not args.no_render,
                      snapshots=getattr(args, "snapshots", 1), from_begin=getattr(args, "from_begin", False),
                      more_targets=tuple(str(t) for t in targets[1:]), target_choice=tuple(chosen),
                      overwrite=getattr(args, "overwrite", False), timeout=_positive_timeout(args),
                      traffic=getattr(args, "traffic", "log"),
                      copy_outside=getattr(args, "copy_outside", False),
                      reaction_time=getattr(args, "reaction_time", 1.0), avoidable=getattr(args, "avoidable", "any"),
                      started=time.perf_counter() - progress.process_age_s())
    result = _supervised_run(opts, progress.bars(quiet=args.quiet))
    entries = result.targets if isinstance(result, RunSummary) else (TargetEntry(result.target, result=result),)
    results: list[TargetResult] = []
    for entry in entries:  # several targets: one folder each
        if entry.result is None:
            lines.append(f"target {entry.target}: no scenario ({entry.error})")
            continue
        results.append(entry.result)
        lines += target_lines(entry.result)
        failed += [(entry.target, f) for f in entry.result.failed]
    folders = [one.folder for one in results]
    for target, f in failed:  # one line each, on stderr like every failure; the other variants are kept
        print(f"coster-sumo: error: {args.config}: target {target}, adversary {f['candidate']} (t_col "
              f"{f['t_col']:.1f} s): {f['reason']}; its variant is left out, the others are kept",
              file=sys.stderr, flush=True)
    if export != "sumo":
        from coster_sumo.exports.run_folder import OSC_DIR, export_run

        for one in results:
            export_run(one, export)
            lines.append(f"OpenSCENARIO: {one.folder}/variants/*/{OSC_DIR}/")
    if not args.quiet:  # --quiet: no progress bars and no file list, the results still
        renders = "; renders: {f}/overview.png, {f}/variants/*/render.png" if not args.no_render else ""
        lines += [f"wrote {f}/summary.json" + renders.format(f=f) for f in folders]
        if len(folders) != 1 or folders[0] != args.out:
            lines.append(f"targets listed in {args.out}/summary.json")
        declared = args.out / "sumo-outputs" / "declared.json"
        if declared.is_file():  # what the configuration asks SUMO to write, from the nominal pass
            lines.append(f"the configuration's own SUMO outputs: {declared.parent}/ (listed in {declared.name})")
    print("\n".join(lines))
    sys.stdout.flush()
    return 1 if failed else 0  # 1: the work ran, some variants failed (each named above)


def _supervised_run(opts: RunOptions, bars: Bars) -> RunResult:
    """:func:`coster_sumo.pipeline.run.run` in a child process: a SUMO crash is one line, and whatever stops
    the run (a crash, Ctrl-C) leaves nothing beside OUT (the old OUT, if any, stays as it was).

    Only where this process has not loaded torch yet (the command line): a process that has run
    torch cannot fork a child that runs it again (its thread pools' locks stay taken in the child:
    a test calling ``main`` after others hung in the CVAE), so such a caller runs in-process.
    """
    from coster_sumo.infra.outdir import OutputLock, clean_leftovers
    from coster_sumo.infra.procs import run_supervised

    if "torch" in sys.modules and not procs.imports_only():
        return run_scenario(opts, bars)
    try:
        result: RunResult = run_supervised(functools.partial(run_scenario, opts, bars), f"run of {opts.spec.config}")
    except BaseException as exc:
        if not isinstance(exc, InputError):  # an input error stopped it before it wrote anything
            # the child's own children (held copies) die with it: wait for them to let go of the lock
            with contextlib.suppress(CosterError, OSError), OutputLock(opts.out, wait_s=10.0):
                clean_leftovers(opts.out)
        raise
    return result


def _positive_timeout(args: argparse.Namespace) -> float | None:
    timeout = getattr(args, "timeout", None)
    if timeout is not None and not timeout > 0:
        raise InputError(f"--timeout must be a positive number of seconds, not {timeout:g}")
    return timeout


# a target that stood still this long and for this share of its time gets a note under its results
STILL_NOTE_MIN_S = 30.0
STILL_NOTE_SHARE = 0.8


def target_lines(result: TargetResult) -> list[str]:
    """The one-line results of one target: its collision times, then a line per variant."""
    r = result
    lines = [f"target {r.target}: t_col = " + ", ".join(f"{s.t_col:.1f} s" for s in r.snapshots)
             + f" ({r.collision_time_method}, init {r.init_method}), planner {r.planner}, adversary {r.adversary}"]
    if r.nominal_cut_after_s:
        lines.append(f"  note: the nominal pass stopped {r.nominal_cut_after_s:.0f} s after "
                     f"{r.target} departed (at {r.nominal_until_s:.1f} s; it had not arrived): "
                     "--begin/--end choose another part of its life")
    motion = r.target_motion
    if motion.in_window_s >= STILL_NOTE_MIN_S and motion.stopped_s >= STILL_NOTE_SHARE * motion.in_window_s:
        lines.append(f"  note: {r.target} stood still for {motion.stopped_s:.0f} s of its "
                     f"{motion.in_window_s:.0f} s in the nominal pass (a jam or gridlock in the configuration); "
                     "its contacts are with a standing vehicle")
    lines += [variant_line(v) for v in r.variants]
    if r.avoidable_only is not None:
        a = r.avoidable_only
        lines.append(f"  --avoidable only: {a.kept} avoidable of {a.tried} variants tried "
                     f"({a.extra_draws} extra draws)")
    lines += dropped_lines(r)
    return lines


OFF_AREA = {"pedestrian": "walkable", "cyclist": "rideable"}  # the area a VRU adversary left


def variant_line(v: VariantOutcome) -> str:
    """A variant's result in one line: its contact (or why none), its approach, what else happened,
    the planner's outcome and the label."""
    hit = (f"contact at {v.collision_time:.1f} s ({v.contact_offset_s:+.1f} s), "
           f"{v.relative_speed:.1f} m/s, {round(v.impact_angle or 0.0):d} deg") if v.collision else (
        "no contact: " + (v.no_contact_reason or "no reason recorded"))
    others = v.other_collisions_list
    approach = (f"; approach {v.approach_m:.0f} m from {v.plan_start_s:.1f} s" if v.approach_m is not None else "")
    who = "" if v.adversary_class == "vehicle" else f" ({v.adversary_class})"
    return (f"  variant {v.variant}{who}: {hit}" + approach
            + (f"; adversary off-{OFF_AREA.get(v.adversary_class, 'road')}" if v.adversary_off_road else "")
            + (f"; {len(others)} other collision{'s' if len(others) != 1 else ''} ({others[0]}"
               + (", ..." if len(others) > 1 else "") + ")" if others else "")
            + (f"; no SUMO export ({v.export_error})" if v.export_error else "")
            + (f"; {v.outcome}" if v.outcome else "")
            + (f"; {v.label}" if v.label else ""))


def dropped_lines(result: TargetResult) -> list[str]:
    """One line per candidate that did not become a variant, with its reason, and how many of the
    variants asked for were kept."""
    lines: list[str] = []
    asked = result.options.get("variants")
    for s in result.snapshots:
        for d in s.dropped:
            c = d["candidate"]
            lines.append(f"  dropped {'candidate ' + str(c) if isinstance(c, int) else c}: {d['reason']}")
        for t, why in s.given_up.items():
            lines.append(f"  gave up {t}: {why}")
    n, wanted = len(result.variants), None if asked is None else asked * len(result.snapshots)
    if wanted is not None and n < wanted:
        lines.insert(0, f"  {n} of {wanted} variants kept; the others:")
    return lines
