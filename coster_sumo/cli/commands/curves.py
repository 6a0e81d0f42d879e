"""``coster-sumo eval curves``: learning curves of training runs as a picture for the model cards."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from coster_sumo.errors import InputError, not_found


def register(cli) -> None:  # type: ignore[no-untyped-def]
    p = cli.group("eval", help="evaluate a model").add_parser(
        "curves", help="plot the learning curves of training runs (their metrics JSON) into a PNG",
        description="METRICS are the .json files `train rollout` / `train prior` write beside their checkpoint "
                    "(one record per epoch). Label a run with LABEL=PATH. A file may list its own vertical marks as "
                    "\"marks\": [[EPOCH, TEXT], ...] (a run continued with --init at another rate, whose "
                    "histories were joined).")
    p.add_argument("metrics", nargs="+", metavar="METRICS",
                   help="metrics JSON of a training run, optionally LABEL=PATH")
    p.add_argument("-o", "--out", "--output", dest="out", type=Path, required=True, metavar="PNG",
                   help="PNG to write")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from coster_sumo.pipeline import viz

    runs = {}
    marks: dict[int, str] = {}
    for item in args.metrics:
        label, sep, name = item.partition("=")
        path = Path(name if sep else item)
        if not path.is_file():
            raise not_found(path)
        try:
            metrics = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise InputError(f"{path}: not a JSON metrics file ({exc})") from exc
        rows = viz.training_history(metrics)
        tcfg = metrics.get("train_config") or {}
        if tcfg.get("lr_drop_epoch"):  # `train rollout --lr-drop-epoch`
            marks[int(tcfg["lr_drop_epoch"])] = f"lr x {tcfg.get('lr_drop_factor', 0.1):g}"
        for mark in metrics.get("marks") or []:
            try:
                marks[int(mark[0])] = str(mark[1])
            except (TypeError, ValueError, IndexError):
                raise InputError(f"{path}: a mark is [EPOCH, TEXT], not {mark!r}") from None
        if not rows:
            raise InputError(f"{path}: no per-epoch records ('epochs' or 'history')")
        runs[label if sep else path.stem] = rows
    out = viz.training_curves(runs, args.out, marks)
    if not args.quiet:
        print(f"{out}: {', '.join(f'{k} ({len(v)} epochs)' for k, v in runs.items())}")
    return 0
