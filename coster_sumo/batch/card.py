"""The corpus card: what a corpus holds, per network and overall, as markdown + PNG histograms.

Read from ``DATASET/manifest.json`` (networks, runs, provenance) and ``DATASET/stats/<run>.npz``
(written by the runs: one sample per vehicle and simulated second, and one row per clip; see
:mod:`coster_sumo.batch.simulate`). Nothing is re-simulated, so the card is cheap to regenerate.

Definitions (also printed in the card):

- road class: the speed limit of the lane a vehicle is on: <= 40, 40-60, 60-90, > 90 km/h;
- lateral speed: SUMO's own lateral speed of the vehicle on its lane (sublane model and continuous
  lane changes), [m/s];
- a clip is *congested* when the median of the mean speeds of its moving vehicles (those above
  0.5 m/s at some step: vehicles stopped all clip long, at a red light or parked, are left out) is
  below 5 m/s; *free flow* when that median is at least 70 % of the median speed limit of the
  clip's lanes.
"""

from __future__ import annotations

import contextlib
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.batch import corpus
from coster_sumo.batch.records import CorpusManifest, NetworkRecord, RunRecord
from coster_sumo.batch.simulate import STATS_DIR
from coster_sumo.data import dataset as ds
from coster_sumo.errors import InputError
from coster_sumo.infra.atomic import atomic_path, write_text

ROAD_CLASSES = ((0.0, 40.0, "<= 40 km/h"), (40.0, 60.0, "40-60 km/h"), (60.0, 90.0, "60-90 km/h"),
                (90.0, 1e9, "> 90 km/h"))
CONGESTED_MPS = 5.0
FREE_FLOW_SHARE = 0.7
CARD = "card.md"
CARD_DIR = "card"


def _load_stats(dataset: Path, runs: list[RunRecord]) -> dict[str, dict[str, np.ndarray]]:
    """run id -> its ``stats/<run>.npz`` arrays (runs without one left out)."""
    out = {}
    for r in runs:
        path = dataset / STATS_DIR / f"{r.run_id}.npz"
        if path.exists():
            with np.load(path) as d:
                out[r.run_id] = {k: d[k] for k in d.files}
    return out


def _cat(parts: list[np.ndarray]) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(0, np.float32)


def _q(a: np.ndarray, q: float) -> str:
    a = a[np.isfinite(a)]
    return f"{np.quantile(a, q):.1f}" if len(a) else "-"


def _hist(path: Path, title: str, xlabel: str, series: dict[str, np.ndarray], bins: Any, log: bool = False) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.6), dpi=90)
    for label, a in series.items():
        a = a[np.isfinite(a)]
        if len(a):
            ax.hist(a, bins=bins, histtype="step", linewidth=1.4, density=True, label=f"{label} (n={len(a)})")
    ax.set_title(title)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("density")
    if log:
        ax.set_yscale("log")
    ax.legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def _declared_sizes() -> dict[str, list[float]]:
    """vClass -> the lengths the corpus vTypes declare."""

    xml, _ = corpus.vtypes_xml(np.random.default_rng(0), freeway=False)
    out: dict[str, list[float]] = defaultdict(list)
    for line in xml.splitlines():
        if "<vType " in line:
            fields = dict(part.split("=", 1) for part in line.split() if "=" in part)
            out[fields["vClass"].strip('"')].append(float(fields["length"].strip('"')))
    return {k: sorted(set(v)) for k, v in out.items()}


@dataclass(frozen=True)
class NetworkRow:
    """One line of the card's "Networks" table.

    Attributes:
        size: the net's lanes, lane km and junctions; None when its file is not there.
        hours: [h] simulated over its runs.
        speed_p50, speed_p95, speed_max: [m/s] as printed ("-" without samples); agents_p50 likewise.
        levels: the demand levels of its runs.
    """

    name: str
    family: str
    source: str
    heldout: bool
    freeway: bool
    runs: int
    hours: float
    clips: int
    vclasses: list[str]
    speed_p50: str
    speed_p95: str
    speed_max: str
    agents_p50: str
    levels: list[str]
    size: corpus.NetSize | None = None


@dataclass(frozen=True)
class CardData:
    """Everything the card shows: the manifest, its finished runs, their stats (run id -> arrays), one
    row per network with runs."""

    manifest: CorpusManifest
    runs: list[RunRecord]
    stats: dict[str, dict[str, np.ndarray]]
    rows: list[NetworkRow]


def _net_size(dataset: Path, info: NetworkRecord) -> corpus.NetSize | None:
    """The net's lanes, lane km and junctions, or None when its file is not there (or unreadable)."""
    net_path = Path(info.net)
    net_path = net_path if net_path.is_absolute() else dataset / net_path
    if info.net and net_path.exists():
        with contextlib.suppress(Exception):
            return corpus.net_size(net_path)
    return None


def card_data(dataset: Path) -> CardData:
    """Everything the card shows (also handy in tests)."""
    manifest = CorpusManifest.from_json(ds.read_manifest(dataset))
    runs = [r for r in manifest.runs if r.ok]
    stats = _load_stats(dataset, runs)
    by_net: dict[str, list[RunRecord]] = defaultdict(list)
    for r in runs:
        by_net[r.network_name].append(r)
    networks = {n.name: n for n in manifest.networks}
    rows = []
    for name, net_runs in sorted(by_net.items()):
        info = networks.get(name, NetworkRecord(name=name))
        st = [stats[r.run_id] for r in net_runs if r.run_id in stats]
        size = _net_size(dataset, info)
        speed = _cat([s["speed"] for s in st])
        vclasses = sorted(set(_cat([s["vclass"] for s in st]).tolist())) if st else []
        rows.append(NetworkRow(
            name=name, family=info.family, source=info.source, heldout=info.heldout, freeway=info.freeway, size=size,
            runs=len(net_runs), hours=sum(r.duration_s for r in net_runs) / 3600.0,
            clips=sum(r.clips for r in net_runs), vclasses=vclasses,
            speed_p50=_q(speed, 0.5), speed_p95=_q(speed, 0.95),
            speed_max=f"{speed.max():.1f}" if len(speed) else "-",
            agents_p50=_q(_cat([s["clip_agents"] for s in st]), 0.5),
            levels=sorted({r.level for r in net_runs})))
    return CardData(manifest=manifest, runs=runs, stats=stats, rows=rows)


@dataclass(frozen=True)
class _Pool:
    """The per-run stats of a corpus, pooled over its runs (``where``: only the runs it accepts)."""

    stats: dict[str, dict[str, np.ndarray]]
    run_of: dict[str, RunRecord]

    def __call__(self, key: str, where: Callable[[RunRecord], bool] | None = None) -> np.ndarray:
        return _cat([s[key] for rid, s in self.stats.items() if where is None or where(self.run_of[rid])])

    def runs_with(self, key: str) -> int:
        """How many runs' stats hold ``key`` (builds before it was written lack it)."""
        return sum(key in s for s in self.stats.values())


@dataclass(frozen=True)
class _Samples:
    """The pooled samples the card's totals, tables and histograms share (one per vehicle and
    simulated second, or one per clip for ``clip_*``)."""

    speed: np.ndarray
    limit_kmh: np.ndarray
    vclass: np.ndarray
    length: np.ndarray
    width: np.ndarray
    is_freeway: np.ndarray  # bool, per speed sample: on a freeway network
    lat_sublane: np.ndarray
    lat_other: np.ndarray
    clip_median: np.ndarray
    clip_limit: np.ndarray
    classes: list[str]
    vru_hours: tuple[float, float, int]  # [h] pedestrian and cyclist track time in clips; runs that counted it

    @classmethod
    def of(cls, pool: _Pool, rows: list[NetworkRow]) -> _Samples:
        freeway = {row.name for row in rows if row.freeway}
        stats, run_of = pool.stats, pool.run_of
        vclass = pool("vclass")
        is_fw = np.concatenate([np.full(len(s["speed"]), run_of[rid].network in freeway)
                                for rid, s in stats.items()]) if stats else np.zeros(0, bool)
        return cls(speed=pool("speed"), limit_kmh=pool("limit") * 3.6, vclass=vclass, length=pool("length"),
                   width=pool("width"), is_freeway=is_fw,
                   lat_sublane=pool("lat_speed", lambda r: r.sublane),
                   lat_other=pool("lat_speed", lambda r: not r.sublane),
                   clip_median=pool("clip_median_speed"), clip_limit=pool("clip_speed_limit"),
                   classes=sorted(set(vclass.tolist())), vru_hours=_vru_hours(pool))


def _vru_hours(pool: _Pool) -> tuple[float, float, int]:
    """[h] pedestrian and cyclist track time in the clips of the runs that counted it, and those runs."""
    runs = pool.runs_with("clip_ped_s")
    if not runs:
        return 0.0, 0.0, 0
    counted = {rid: st for rid, st in pool.stats.items() if "clip_ped_s" in st}
    part = _Pool(counted, pool.run_of)
    return float(part("clip_ped_s").sum()) / 3600.0, float(part("clip_cyclist_s").sum()) / 3600.0, runs


def _draw_histograms(figs: Path, s: _Samples, pool: _Pool) -> None:
    speed, is_fw = s.speed, s.is_freeway
    _hist(figs / "speed_by_road_class.png", "speed by road class (lane speed limit)", "speed [m/s]",
          {label: speed[(s.limit_kmh > lo) & (s.limit_kmh <= hi)] for lo, hi, label in ROAD_CLASSES},
          np.arange(0, 45, 1.0))
    _hist(figs / "speed_freeway.png", "speed: freeway networks vs the rest", "speed [m/s]",
          {"freeway networks": speed[is_fw], "other networks": speed[~is_fw]}, np.arange(0, 45, 1.0))
    _hist(figs / "acceleration.png", "longitudinal acceleration", "acceleration [m/s²]",
          {"all": pool("accel")}, np.arange(-9, 5, 0.25), log=True)
    _hist(figs / "lateral_speed.png", "lateral speed (SUMO's, on the lane)", "lateral speed [m/s]",
          {"sublane runs": s.lat_sublane, "other runs": s.lat_other}, np.arange(-3, 3.05, 0.1), log=True)
    _hist(figs / "length_by_class.png", "vehicle length by class", "length [m]",
          {c: s.length[s.vclass == c] for c in s.classes}, np.arange(0, 20, 0.25))
    _hist(figs / "width_by_class.png", "vehicle width by class", "width [m]",
          {c: s.width[s.vclass == c] for c in s.classes}, np.arange(0.4, 3.0, 0.05))
    _hist(figs / "agents_per_clip.png", "agents per clip", "agents", {"clips": pool("clip_agents")},
          np.arange(0, 200, 4))
    _hist(figs / "clip_median_speed.png", "clip median speed of moving vehicles", "speed [m/s]",
          {"clips": s.clip_median}, np.arange(0, 40, 1.0))


def _totals_lines(dataset: Path, manifest: CorpusManifest, runs: list[RunRecord], rows: list[NetworkRow],
                  s: _Samples) -> list[str]:
    """The card's heading and its "Totals" section."""
    hours = manifest.simulated_hours
    wall = sum(r.wall_s for r in runs)
    cpu_s = [r.cpu_s for r in runs if r.cpu_s is not None]
    cpu_h = sum(cpu_s) / 3600.0
    cpu_rate = sum(r.duration_s for r in runs if r.cpu_s is not None) / 3600.0 / cpu_h if cpu_h > 0 else float("nan")
    train_clips = len(ds.list_scenes(dataset)) if ds.scenes_dir(dataset).is_dir() else 0
    heldout_clips = len(ds.list_heldout(dataset))
    speed, is_fw, lat_sub, lat_other = s.speed, s.is_freeway, s.lat_sublane, s.lat_other
    congested = int(np.sum(s.clip_median < CONGESTED_MPS))
    free = int(np.sum(s.clip_median >= FREE_FLOW_SHARE * s.clip_limit))
    return [
        "# Corpus card", "",
        f"Generated by `coster-sumo corpus card` from `{ds.MANIFEST}` and `{STATS_DIR}/` "
        "(definitions: docs/corpus.md).", "",
        "## Totals", "",
        f"- networks with runs: **{len(rows)}** (catalogue: {len(manifest.networks)}); "
        f"held out: {', '.join(manifest.heldout_networks) or 'none'}",
        f"- runs: {len(runs)} ok, {manifest.runs_failed} failed; simulated: **{hours:.2f} h** "
        f"(warm-up included)",
        f"- clips (9.1 s, 10 Hz): {train_clips} for training/validation (`scenes/`), {heldout_clips} held out "
        f"(`heldout/`)",
        f"- run wall time (sum over runs, one process each): {wall / 3600:.2f} h, i.e. "
        f"{hours / max(wall / 3600, 1e-9):.1f} simulated h per process-hour (wall time depends on the machine's "
        f"load); CPU time of the {len(cpu_s)} runs that measured it: {cpu_h:.2f} h, {cpu_rate:.1f} simulated h "
        "per CPU-hour",
        f"- vehicle classes ({len(s.classes)}): {', '.join(s.classes)}",
        f"- freeway networks: {np.mean(speed[is_fw] > 30) if is_fw.any() else 0:.1%} of samples above 30 m/s "
        f"(max {speed[is_fw].max() if is_fw.any() else 0:.1f} m/s)",
        f"- lateral speed beyond 0.5 m/s: {np.mean(np.abs(lat_sub) > 0.5) if len(lat_sub) else 0:.2%} of samples in "
        f"sublane runs, {np.mean(np.abs(lat_other) > 0.5) if len(lat_other) else 0:.2%} in the others",
        f"- clips: {congested} congested (median moving speed < {CONGESTED_MPS:g} m/s), {free} free flow "
        f"(>= {FREE_FLOW_SHARE:.0%} of the speed limit), of {len(s.clip_median)}",
        f"- vulnerable road users in the clips: **{s.vru_hours[0]:.3f} h** of pedestrian and "
        f"**{s.vru_hours[1]:.3f} h** of cyclist tracks (valid steps x 0.1 s, summed over clips; "
        f"{s.vru_hours[2]} of {len(runs)} runs counted them)",
        ""]


def _class_and_speed_lines(s: _Samples) -> list[str]:
    """The "Vehicle classes" and "Speeds by road class" tables."""
    lines = [
        "## Vehicle classes", "",
        "Lengths and widths seen (SUMO's values), against those the corpus vTypes declare (networks with "
        "their own demand bring their own types).", "",
        "| class | samples | lengths seen [m] (share) | declared lengths [m] | widths seen [m] |",
        "|---|---|---|---|---|"]
    declared = _declared_sizes()
    for c in s.classes:
        m = s.vclass == c
        values, counts = np.unique(np.round(s.length[m], 2), return_counts=True)
        top = np.argsort(-counts)[:8]
        ls = ", ".join(f"{values[i]:g} ({counts[i] / m.sum():.0%})" for i in sorted(top))
        ws = ", ".join(f"{v:g}" for v in np.unique(np.round(s.width[m], 2))[:8])
        lines.append(f"| {c} | {int(m.sum())} | {ls} | {', '.join(f'{v:g}' for v in declared.get(c, [])) or '-'} "
                     f"| {ws} |")
    lines += ["", "## Speeds by road class (lane speed limit)", "",
              "| road class | samples | stopped (< 0.5 m/s) | p5 | p50 | p95 [m/s] |", "|---|---|---|---|---|---|"]
    for lo, hi, label in ROAD_CLASSES:
        sp = s.speed[(s.limit_kmh > lo) & (s.limit_kmh <= hi)]
        stopped = f"{np.mean(sp < 0.5):.0%}" if len(sp) else "-"
        lines.append(f"| {label} | {len(sp)} | {stopped} | {_q(sp, 0.05)} | {_q(sp, 0.5)} | {_q(sp, 0.95)} |")
    return lines


def _of_level(level: str) -> Callable[[RunRecord], bool]:
    return lambda r: r.level == level


def _level_and_network_lines(manifest: CorpusManifest, runs: list[RunRecord], rows: list[NetworkRow],
                             pool: _Pool) -> list[str]:
    """The "Demand levels" table, the acceleration line and the "Networks" table."""
    lines = ["", "## Demand levels", "",
             "| level | runs | clips | congested | free flow | clip median moving speed p10 / p50 / p90 [m/s] |",
             "|---|---|---|---|---|---|"]
    for level in sorted({r.level for r in runs}):
        med = pool("clip_median_speed", _of_level(level))
        lim = pool("clip_speed_limit", _of_level(level))
        lines.append(f"| {level} | {sum(r.level == level for r in runs)} | {len(med)} | "
                     f"{int(np.sum(med < CONGESTED_MPS))} | {int(np.sum(med >= FREE_FLOW_SHARE * lim))} | "
                     f"{_q(med, 0.1)} / {_q(med, 0.5)} / {_q(med, 0.9)} |")
    acc = pool("accel")
    lines += ["", f"Acceleration p1 / p50 / p99: {_q(acc, 0.01)} / {_q(acc, 0.5)} / {_q(acc, 0.99)} m/s²; "
              f"agents per clip p10 / p50 / p90: {_q(pool('clip_agents'), 0.1)} / {_q(pool('clip_agents'), 0.5)} / "
              f"{_q(pool('clip_agents'), 0.9)}.", "",
              "## Networks", "",
              "| network | family | held out | source | lanes | lane km | runs | hours | clips | demand levels | "
              "speed p50 / p95 / max [m/s] | agents/clip p50 | classes |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        lanes, lane_km = (row.size.lanes, row.size.lane_km) if row.size else ("-", "-")
        lines.append(f"| {row.name} | {row.family} | {'yes' if row.heldout else ''} | {row.source} | "
                     f"{lanes} | {lane_km} | {row.runs} | {row.hours:.2f} | "
                     f"{row.clips} | {', '.join(row.levels)} | {row.speed_p50} / {row.speed_p95} / "
                     f"{row.speed_max} | {row.agents_p50} | {len(row.vclasses)} |")
    excluded = manifest.wheel_excluded
    if excluded:
        lines += ["", "Wheel networks left out: " + "; ".join(f"{k} ({v})" for k, v in excluded.items()) + "."]
    return lines


def write_card(dataset: Path, output: Path | None = None) -> Path:
    """Write ``card.md`` and ``card/*.png`` (into ``output``, default the dataset folder)."""
    dataset = Path(dataset)
    if not (dataset / ds.MANIFEST).exists():
        raise InputError(f"{dataset}: no {ds.MANIFEST} (not a corpus folder)")
    out = Path(output) if output is not None else dataset
    figs = out / CARD_DIR
    figs.mkdir(parents=True, exist_ok=True)
    data = card_data(dataset)
    manifest, runs, rows = data.manifest, data.runs, data.rows
    pool = _Pool(data.stats, {r.run_id: r for r in runs})
    samples = _Samples.of(pool, rows)
    _draw_histograms(figs, samples, pool)
    lines = _totals_lines(dataset, manifest, runs, rows, samples)
    lines += _class_and_speed_lines(samples)
    lines += _level_and_network_lines(manifest, runs, rows, pool)
    lines += ["", "## Histograms", ""]
    lines += [f"![{p.stem}]({CARD_DIR}/{p.name})" for p in sorted(figs.glob("*.png"))]
    return write_text(out / CARD, "\n".join(lines) + "\n")
