"""The records a dataset's ``manifest.json`` holds about its runs and networks, as types.

``manifest.json`` itself is read and written by :mod:`coster_sumo.data.dataset` (a JSON object: the
totals it recomputes, the runs, and for a corpus its catalogue). The batch modules build and read
its parts through these classes: what a run reports (:class:`RunOutcome`), what the card reads of
a recorded run (:class:`RunRecord`) and of a catalogued network (:class:`NetworkRecord`), and the
manifest as the card sees it (:class:`CorpusManifest`). The JSON keys are the manifest's.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class RunOutcome:
    """What one simulation run reports back (merged into its manifest entry).

    Attributes:
        clips: clips written.
        vehicles: distinct vehicles seen.
        simulated_s: [s] simulated after the run's begin.
        wall_s: [s] wall-clock time of the run.
        cpu_s: [s] CPU time of the run and the tools it started (randomTrips, duarouter).
    """

    clips: int
    vehicles: int
    simulated_s: float
    wall_s: float
    cpu_s: float
    status: str = "ok"

    def to_json(self) -> dict[str, Any]:
        return {"status": self.status, "clips": self.clips, "vehicles": self.vehicles,
                "simulated_s": self.simulated_s, "wall_s": self.wall_s, "cpu_s": self.cpu_s}


@dataclass(frozen=True)
class RunRecord:
    """A run as the manifest lists it (the fields the card reads; the entry holds more).

    Attributes:
        network: the corpus network it ran on; "" for runs of ``coster-sumo simulate``.
        level: the corpus demand level ("-" when none).
        sublane: whether it ran SUMO's sublane model.
        duration_s: [s] simulated (warm-up included).
        wall_s: [s] wall-clock time (0 when not recorded).
        cpu_s: [s] CPU time; None for runs recorded before it was measured.
    """

    run_id: str
    status: str
    network: str = ""
    level: str = "-"
    sublane: bool = False
    clips: int = 0
    duration_s: float = 0.0
    wall_s: float = 0.0
    cpu_s: float | None = None

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def network_name(self) -> str:
        """The network, or for runs without one the run id less its seed suffix."""
        return self.network or self.run_id.rsplit("_", 1)[0]

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> RunRecord:
        return cls(run_id=d["run_id"], status=d.get("status", ""), network=d.get("network", ""),
                   level=d.get("level", "-"), sublane=bool(d.get("sublane")), clips=int(d.get("clips", 0)),
                   duration_s=float(d.get("duration_s", 0.0)), wall_s=float(d.get("wall_s", 0.0)),
                   cpu_s=float(d["cpu_s"]) if "cpu_s" in d else None)


@dataclass(frozen=True)
class NetworkRecord:
    """One network of the corpus catalogue, as the manifest lists it.

    Attributes:
        net: the ``.net.xml``, relative to the dataset when inside it.
        lane_km: [km] of lanes (internal lanes left out); 0 when unknown.
        own_demand: file names of its own route files (empty: random trips).
        source: where it comes from (the wheel, the repository, or the builder and its arguments).
        params: the builder's parameters, for networks this project authors (None otherwise).
    """

    name: str
    family: str = "-"
    net: str = ""
    heldout: bool = False
    lane_km: float = 0.0
    own_demand: tuple[str, ...] = ()
    freeway: bool = False
    source: str = "-"
    params: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"name": self.name, "family": self.family, "net": self.net, "heldout": self.heldout,
                               "lane_km": self.lane_km, "own_demand": list(self.own_demand),
                               "freeway": self.freeway, "source": self.source}
        if self.params is not None:
            out["params"] = self.params
        return out

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> NetworkRecord:
        return cls(name=d["name"], family=d.get("family", "-"), net=d.get("net", ""), heldout=bool(d.get("heldout")),
                   lane_km=float(d.get("lane_km", 0.0)), own_demand=tuple(d.get("own_demand", ())),
                   freeway=bool(d.get("freeway")), source=d.get("source", "-"), params=d.get("params"))


@dataclass(frozen=True)
class CorpusManifest:
    """A dataset's manifest as the corpus card reads it.

    Attributes:
        simulated_hours: [h] simulated by the runs that finished (warm-up included).
        runs_failed: runs listed as failed.
        runs: every run listed, failed ones too.
        networks: the catalogue (empty for datasets of ``coster-sumo simulate``).
        heldout_networks: names of the networks whose clips are held out.
        wheel_excluded: wheel folders left out of the catalogue -> why.
    """

    simulated_hours: float
    runs_failed: int
    runs: tuple[RunRecord, ...] = ()
    networks: tuple[NetworkRecord, ...] = ()
    heldout_networks: tuple[str, ...] = ()
    wheel_excluded: dict[str, str] = field(default_factory=dict)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> CorpusManifest:
        return cls(simulated_hours=float(d["simulated_hours"]), runs_failed=int(d["counts"]["runs_failed"]),
                   runs=tuple(RunRecord.from_json(r) for r in d.get("runs", [])),
                   networks=tuple(NetworkRecord.from_json(n) for n in d.get("networks", [])),
                   heldout_networks=tuple(d.get("heldout_networks", [])),
                   wheel_excluded=dict(d.get("corpus", {}).get("wheel_excluded", {})))


@dataclass(frozen=True)
class BatchCounts:
    """What one batch call did: runs planned, run now and failed now (one line per failure, other
    failures such as a network that could not be built included), clips written now, and the
    dataset's totals after it (clips, simulated hours [h]); ``wall_s`` [s] of the call."""

    runs_planned: int
    runs_done_now: int
    runs_failed_now: int
    clips_now: int
    failures: list[str]
    total_clips: int
    simulated_hours: float
    wall_s: float

    @property
    def ok(self) -> bool:
        return not self.failures

    def to_json(self, total_key: str) -> dict[str, Any]:
        """The counts as a batch's summary.json lists them; ``total_key`` names the dataset's total
        of clips (``simulate`` writes ``total_scenes``, ``corpus build`` ``total_clips``)."""
        return {"runs_planned": self.runs_planned, "runs_done_now": self.runs_done_now,
                "runs_failed_now": self.runs_failed_now, "clips_now": self.clips_now, "failures": self.failures,
                total_key: self.total_clips, "simulated_hours": self.simulated_hours, "wall_s": self.wall_s}


@dataclass(frozen=True)
class SimulateSummary:
    """``DATASET/summary.json`` of ``coster-sumo simulate``: the counts and the configuration (as
    JSON: paths as strings, the sources as given)."""

    dataset: str
    counts: BatchCounts
    config: dict[str, Any]

    def to_json(self) -> dict[str, Any]:
        return {"dataset": self.dataset, **self.counts.to_json("total_scenes"), "config": self.config}


@dataclass(frozen=True)
class CorpusSummary:
    """``DATASET/summary.json`` of ``coster-sumo corpus build``: the counts over ``networks``
    networks."""

    dataset: str
    networks: int
    counts: BatchCounts

    def to_json(self) -> dict[str, Any]:
        return {"dataset": self.dataset, "networks": self.networks, **self.counts.to_json("total_clips")}
