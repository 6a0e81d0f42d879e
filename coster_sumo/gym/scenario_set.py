"""Scenario sets: the folder ``coster-sumo scenarios build`` writes and the environment reads.

A scenario set is everything :class:`coster_sumo.gym.env.ScenarioEnv` needs to start a scenario,
and nothing it has to compute again (docs/gym.md):

```
SET/manifest.json          format, method, seed, the networks and their split, every scenario
SET/nets/<network>.net.xml the SUMO network of each source (copied: the set moves as one folder)
SET/scenarios/<id>.npz     one replay scene per scenario (coster_sumo.formats.scene_file.save_scene)
SET/vtypes.add.xml         the vehicle types the replay adds vehicles with (converted scenes' types)
```

A replay scene is the recorded nominal pass around the target at 10 Hz on SUMO's clock (the
target, every vehicle the pass recorded near it) and, for a generated variant, the adversary's
plan sampled on the same grid as one more agent (``adversaryN``, valid from the plan's start). In
the environment every agent but the target is replayed from it (the agent drives the target),
as a converted WOMD scene replays its log.

The manifest lists each scenario with its network, split (``train`` / ``test``: by network, so a
policy is evaluated on networks it never saw), kind (``nominal`` or ``variant``), the time window
[``t_start``, ``t_end``] [s] and, for variants, ``t_col`` [s] and the adversary's id.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.core.scene import Scene
from coster_sumo.errors import InputError
from coster_sumo.formats.scene_file import load_scene

SET_FORMAT = 1
MANIFEST = "manifest.json"
VTYPES_FILE = "vtypes.add.xml"
SPLITS = ("train", "test")


@dataclass(frozen=True)
class ScenarioEntry:
    """One scenario of a set (a manifest row).

    Attributes:
        id: unique within the set; also the file name ``scenarios/<id>.npz``.
        network: the network's name (the split is by network).
        split: ``train`` or ``test``.
        kind: ``nominal`` (no adversary) or ``variant`` (a generated adversary).
        method: the generator that made it (``nominal`` for nominal scenes).
        source: the scenario spec it came from (``CFG@seed=N...``).
        target: the id of the vehicle the agent drives.
        net: the network file, relative to the set.
        t_start: [s] SUMO time the episode starts (the first step shows this time).
        t_end: [s] SUMO time of the last replayed step.
        t_col: [s] planned contact time with the target's nominal path (variants), else None.
        adversary: the adversary's id in the replay scene (variants), else None.
        staging_lane: a converted WOMD scene's staging lane (see :mod:`coster_sumo.sim.replay`).
        tls: a converted WOMD scene's signal link mapping (``lane_map.json["tls"]``).
        avoidable: whether the target could have avoided the contact, when known.
        extra: free-form provenance (snapshot index, variant index, criticality score ...).
    """

    id: str
    network: str
    split: str
    kind: str
    method: str
    source: str
    target: str
    net: str
    t_start: float
    t_end: float
    t_col: float | None = None
    adversary: str | None = None
    staging_lane: str | None = None
    tls: dict[str, Any] = field(default_factory=dict)
    avoidable: bool | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ScenarioEntry:
        known = {f for f in cls.__dataclass_fields__}
        return cls(**{k: v for k, v in d.items() if k in known})


@dataclass(frozen=True)
class SetNetwork:
    """A network of a scenario set: its split (every scenario on it is in that split) and the
    sources (configurations and their seeds) recorded on it."""

    split: str
    sources: tuple[str, ...] = ()

    def to_json(self) -> dict[str, Any]:
        return {"split": self.split, "sources": list(self.sources)}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> SetNetwork:
        return cls(split=d["split"], sources=tuple(d.get("sources", ())))


@dataclass(frozen=True)
class ScenarioSet:
    """A scenario set read from its folder (only the manifest; scenes load on demand)."""

    root: Path
    method: str
    entries: tuple[ScenarioEntry, ...]
    meta: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def load(cls, root: str | Path) -> ScenarioSet:
        root = Path(root)
        path = root / MANIFEST
        try:
            manifest = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise InputError(f"{path}: not a scenario set manifest ({exc}); build one with "
                             "`coster-sumo scenarios build`") from None
        if manifest.get("format") != SET_FORMAT:
            raise InputError(f"{path}: scenario set format {manifest.get('format')!r}, this version reads {SET_FORMAT}")
        entries = tuple(ScenarioEntry.from_dict(d) for d in manifest.get("scenarios", []))
        return cls(root, str(manifest.get("method", "")), entries,
                   {k: v for k, v in manifest.items() if k != "scenarios"})

    def select(self, split: str | None = None, kind: str | None = None,
               networks: tuple[str, ...] | None = None) -> list[ScenarioEntry]:
        """The entries of a split / kind / set of networks (None: any)."""
        return [e for e in self.entries if (split is None or e.split == split) and (kind is None or e.kind == kind)
                and (networks is None or e.network in networks)]

    def scene(self, entry: ScenarioEntry) -> Scene:
        """The replay scene of ``entry``."""
        return load_scene(self.root / "scenarios" / f"{entry.id}.npz")

    def net_file(self, entry: ScenarioEntry) -> Path:
        return self.root / entry.net

    @property
    def vtypes_file(self) -> Path:
        return self.root / VTYPES_FILE


def write_vtypes(root: Path) -> None:
    """``vtypes.add.xml``: the vTypes :class:`~coster_sumo.sim.replay.LogReplayer` adds agents with."""
    from coster_sumo.formats.scene_folder import VTYPES

    rows = {v[0]: v for v in VTYPES.values()}
    lines = [f'    <vType id="{tid}" vClass="{vclass}" guiShape="{shape}" length="{length}" width="{width}"/>'
             for tid, vclass, shape, length, width in rows.values()]
    (root / VTYPES_FILE).write_text("<additional>\n" + "\n".join(lines) + "\n</additional>\n")


def write_manifest(root: Path, method: str, seed: int, entries: list[ScenarioEntry],
                   networks: dict[str, SetNetwork], options: dict[str, Any]) -> None:
    """Write ``manifest.json`` atomically (the build rewrites it after every source: resumable)."""
    from coster_sumo.infra.atomic import write_json

    splits: dict[str, list[str]] = {s: sorted(n for n, v in networks.items() if v.split == s) for s in SPLITS}
    counts = {s: {k: sum(1 for e in entries if e.split == s and e.kind == k) for k in ("nominal", "variant")}
              for s in SPLITS}
    write_json(root / MANIFEST, {"format": SET_FORMAT, "method": method, "seed": seed, "options": options,
                                 "networks": {n: v.to_json() for n, v in networks.items()}, "splits": splits,
                                 "counts": counts,
                                 "scenarios": [e.to_dict() for e in entries]})


def route_of(scene: Scene, target: int, t_start: float, t_end: float) -> np.ndarray:
    """(P, 2) [m] the target's nominal path between ``t_start`` and ``t_end`` (its valid states)."""
    tr = scene.tracks
    ts = scene.timestamps
    keep = tr.valid[target] & (ts >= t_start - 1e-6) & (ts <= t_end + 1e-6)
    return np.stack([tr.x[target, keep], tr.y[target, keep]], -1)
