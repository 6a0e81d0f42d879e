"""A COSTER set without augmentation, taken from one with it instead of generating again.

``--method coster-one-per-snapshot`` keeps the first plan of each snapshot
(:data:`coster_sumo.gym.build.METHODS`); every plan of a snapshot is generated, labelled and saved
on its own, so that set is the ``coster`` set of the same sources and options less the variants
after the first of each snapshot, renamed. Building it again costs the whole generation once more
(about 5 s per clip, 90 minutes for issue 61's 1,058 training clips on one core);
:func:`one_per_snapshot` takes it from the ``coster`` set in seconds, and
``tests/gym_env/test_derive.py`` checks that both ways give the same manifest and scenes.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

from coster_sumo.errors import InputError
from coster_sumo.gym.scenario_set import MANIFEST, VTYPES_FILE, ScenarioEntry, ScenarioSet, SetNetwork, write_manifest

FROM_METHOD = "coster"
METHOD = "coster-one-per-snapshot"


def _renamed(entry: ScenarioEntry) -> ScenarioEntry:
    """``entry`` as the one-per-snapshot build names it (its id holds the method)."""
    if entry.kind != "variant":
        return entry
    mark = f"_{FROM_METHOD}_k"
    head, sep, tail = entry.id.rpartition(mark)
    if not sep:
        raise InputError(f"scenario {entry.id!r}: not a {FROM_METHOD} variant's id")
    d = entry.to_dict() | {"id": f"{head}_{METHOD}_k{tail}", "method": METHOD}
    return ScenarioEntry.from_dict(d)


def _link(src: Path, dst: Path) -> None:
    """``dst`` as a hard link to ``src`` (a copy across file systems)."""
    if dst.exists():
        dst.unlink()
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)


def one_per_snapshot(src: str | Path, out: str | Path) -> dict[str, Any]:
    """Write the ``coster-one-per-snapshot`` set of the ``coster`` set ``src`` into ``out`` (created;
    it must not hold another set); returns its manifest's counts. Scene and network files are hard
    links where the file system allows."""
    src, out = Path(src), Path(out)
    cset = ScenarioSet.load(src)
    if cset.method != FROM_METHOD:
        raise InputError(f"{src}: a {cset.method!r} set; the variants of one snapshot come from a "
                         f"{FROM_METHOD!r} set")
    options = dict(cset.meta.get("options", {}))
    if options.get("failed") is None or options.get("done_sources") is None:
        raise InputError(f"{src / MANIFEST}: no build progress in its options (not written by `scenarios build`)")
    if (out / MANIFEST).exists() and json.loads((out / MANIFEST).read_text()).get("method") != METHOD:
        raise InputError(f"{out}: holds another set; choose an empty folder")
    kept = [e for e in cset.entries if e.kind == "nominal" or e.extra.get("variant") == 0]
    keep = [_renamed(e) for e in kept]
    (out / "scenarios").mkdir(parents=True, exist_ok=True)
    (out / "nets").mkdir(exist_ok=True)
    for old, new in zip(kept, keep, strict=True):
        _link(src / "scenarios" / f"{old.id}.npz", out / "scenarios" / f"{new.id}.npz")
    for net in sorted({e.net for e in cset.entries} | {f"nets/{n}.net.xml" for n in cset.meta.get("networks", {})}):
        if (src / net).exists():
            _link(src / net, out / net)
    shutil.copyfile(src / VTYPES_FILE, out / VTYPES_FILE)
    networks = {n: SetNetwork.from_json(v) for n, v in cset.meta.get("networks", {}).items()}
    write_manifest(out, METHOD, int(cset.meta.get("seed", 0)), keep, networks, options | {"method": METHOD})
    return {"scenarios": len(keep), "variants": sum(e.kind == "variant" for e in keep)}
