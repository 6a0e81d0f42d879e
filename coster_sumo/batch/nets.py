"""Networks the corpus authors: freeway sections, roundabouts, rural roads, netgenerate families.

Every builder is deterministic in its index and seed (a numpy generator seeded with both), writes
its plain XML (nodes, edges) next to the net, and runs ``netconvert`` / ``netgenerate`` from the
``sumo`` package (:mod:`coster_sumo.infra.sumo_install`). Each returns the options it drew, which the corpus
manifest records as the network's provenance. What the freeway layout means in traffic terms
(merges, diverges, weaving) is described in docs/corpus.md.
"""

from __future__ import annotations

import math
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.data import dataset as ds
from coster_sumo.infra.atomic import atomic_path, write_text

KMH = 1.0 / 3.6  # [m/s] per km/h
NO_BIKES = 'disallow="pedestrian bicycle"'


# ----------------------------------------------------------------------------- netgenerate

_SPEEDS_MPS = (8.33, 11.11, 13.89, 16.67, 22.22)  # 30 / 40 / 50 / 60 / 80 km/h
_JUNCTIONS = ("traffic_light", "priority", "right_before_left", "allway_stop")



@dataclass(frozen=True)
class Source:
    """Something to simulate.

    Attributes:
        name: unique short name (file stem), used in run and scene names.
        path: the ``.sumocfg``, or the ``.net.xml``.
        is_config: a ``.sumocfg`` (else a net).
        has_demand: the configuration names route files, or ``routes`` are given (else random trips).
        end_s: [s] the configuration's own end time, if it sets one.
        begin_s: [s] the configuration's own begin time (0 when it sets none).
        routes: route files for a net run with its own demand (``is_config`` False).
        additional: additional files for such a net (vTypes, traffic light programs).
    """

    name: str
    path: Path
    is_config: bool
    has_demand: bool
    end_s: float | None = None
    begin_s: float = 0.0
    routes: tuple[Path, ...] = ()
    additional: tuple[Path, ...] = ()


def netgenerate_options(k: int, seed: int, speeds: tuple[float, ...] = _SPEEDS_MPS) -> tuple[str, list[str]]:
    """The kind ("grid", "spider", "random") and netgenerate options of generated network ``k``.

    Kinds cycle through the three; sizes, lane counts, speeds (from ``speeds`` [m/s]) and junction
    control are drawn from a generator seeded with (seed, k), so the same k and seed give the same
    network.
    """
    rng = np.random.default_rng([seed, k, 7])
    kind = ("grid", "spider", "random")[k % 3]
    lanes = int(rng.integers(1, 4))
    speed = float(rng.choice(speeds))
    junction = str(rng.choice(_JUNCTIONS, p=[0.45, 0.3, 0.15, 0.1]))
    opts = ["--default.lanenumber", str(lanes), "--default.speed", f"{speed:g}",
            "--default-junction-type", junction, "--tls.default-type",
            str(rng.choice(["static", "actuated"])), "--seed", str(seed * 1000 + k)]
    if kind == "grid":
        opts = ["--grid", "--grid.x-number", str(int(rng.integers(3, 7))),
                "--grid.y-number", str(int(rng.integers(3, 6))),
                "--grid.x-length", f"{rng.uniform(90, 250):.0f}",
                "--grid.y-length", f"{rng.uniform(90, 250):.0f}",
                "--grid.attach-length", f"{rng.uniform(60, 150):.0f}", *opts]
    elif kind == "spider":
        opts = ["--spider", "--spider.arm-number", str(int(rng.integers(4, 8))),
                "--spider.circle-number", str(int(rng.integers(2, 5))),
                "--spider.space-radius", f"{rng.uniform(60, 140):.0f}",
                "--spider.attach-length", f"{rng.uniform(60, 150):.0f}", *opts]
        if rng.random() < 0.5:
            opts.append("--spider.omit-center")
    else:
        opts = ["--rand", "--rand.iterations", str(int(rng.integers(40, 140))),
                "--rand.min-distance", "80", "--rand.max-distance", "250",
                "--rand.random-lanenumber", "--rand.random-priority", "--tls.guess", "true", *opts]
        if rng.random() < 0.5:
            opts.append("--rand.grid")
    return kind, opts


def run_tool(cmd: list[str], what: str, cwd: Path | None = None) -> None:
    """Run a SUMO binary or tool; :class:`RuntimeError` with the tail of its output when it fails."""
    from coster_sumo.infra import sumo_install

    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=cwd, env=sumo_install.subprocess_env())
    if proc.returncode != 0:
        msg = " ".join((proc.stderr or proc.stdout).split())[-300:]
        raise RuntimeError(f"{what} failed: {msg or f'exit code {proc.returncode}'}")


def netgenerate(path: Path, opts: list[str]) -> None:
    """Write ``path`` with ``netgenerate opts`` (atomically: kept only when netgenerate succeeded)."""
    from coster_sumo.infra import sumo_install

    with atomic_path(path) as tmp:
        run_tool([sumo_install.binary("netgenerate"), *opts, "--output-file", str(tmp)], "netgenerate")
        if not tmp.exists():
            raise RuntimeError("netgenerate wrote no network")


def generate_nets(dataset: Path, count: int, seed: int) -> tuple[list[Any], list[dict], list[str]]:
    """Make ``count`` networks under ``DATASET/nets/`` (kept when already there), for ``coster-sumo
    simulate --netgenerate``.

    Returns the sources (:class:`coster_sumo.batch.simulate.Source`), their manifest records, and
    one-line errors for nets that failed.
    """

    sources, records, errors = [], [], []
    for k in range(count):
        kind, opts = netgenerate_options(k, seed)
        name = f"gen{k:03d}_{kind}"
        path = dataset / ds.NETS_DIR / f"{name}.net.xml"
        path.parent.mkdir(parents=True, exist_ok=True)
        if not path.exists():
            try:
                netgenerate(path, opts)
            except RuntimeError as exc:
                errors.append(f"{name}: {exc}")
                continue
        sources.append(Source(name=name, path=path, is_config=False, has_demand=False))
        records.append({"name": name, "kind": kind, "path": str(path.relative_to(dataset)),
                        "netgenerate": opts})
    return sources, records, errors


def _netconvert(folder: Path, stem: str, net: Path, extra: list[str]) -> None:
    from coster_sumo.infra import sumo_install

    with atomic_path(net) as tmp:
        run_tool([sumo_install.binary("netconvert"), "--node-files", str(folder / f"{stem}.nod.xml"),
                  "--edge-files", str(folder / f"{stem}.edg.xml"), "--no-turnarounds", "true",
                  "--output-file", str(tmp), *extra], "netconvert")


def _write_plain(folder: Path, stem: str, nodes: list[str], edges: list[str]) -> None:
    write_text(folder / f"{stem}.nod.xml", "<nodes>\n" + "\n".join(nodes) + "\n</nodes>\n")
    write_text(folder / f"{stem}.edg.xml", "<edges>\n" + "\n".join(edges) + "\n</edges>\n")


def freeway(net: Path, k: int, seed: int) -> dict[str, Any]:
    """A one-direction freeway section with an on-ramp, a weaving section and an off-ramp.

    Main line: 2-5 lanes at 80-130 km/h over 3.5-5.5 km, gently bent. In order: an on-ramp whose
    lane becomes an auxiliary lane; that lane ends at an off-ramp (the weaving section between
    them, 250-600 m); a second on-ramp with an acceleration lane that drops after 200-300 m; a
    second off-ramp near the end. Ramps: one lane at 60-80 km/h. No bicycles or pedestrians.
    """
    rng = np.random.default_rng([seed, k, 11])
    lanes = int(rng.integers(2, 6))
    speed_kmh = float(rng.choice([80, 100, 110, 120, 130]))
    ramp_kmh = float(rng.choice([60, 70, 80]))
    weave = float(rng.uniform(250, 600))
    accel = float(rng.uniform(200, 300))
    seg = rng.uniform([700, 600, 500, 500], [1300, 1400, 900, 900])
    xs = np.cumsum([0.0, seg[0], weave, seg[1], accel, seg[2], seg[3]])  # n0 .. n6
    bend = float(rng.uniform(-0.02, 0.02))  # [1/m * m] lateral drift per metre: a gentle curve
    ys = bend * xs ** 1.5 / 40.0
    names = ["n0", "on1", "off1", "on2", "drop2", "off2", "n6"]
    nodes = [f'    <node id="{n}" x="{x:.1f}" y="{y:.1f}" type="priority"/>'
             for n, x, y in zip(names, xs, ys, strict=True)]
    nodes += [f'    <node id="r_on1" x="{xs[1] - 350:.1f}" y="{ys[1] - 60:.1f}" type="priority"/>',
              f'    <node id="r_off1" x="{xs[2] + 350:.1f}" y="{ys[2] - 60:.1f}" type="priority"/>',
              f'    <node id="r_on2" x="{xs[3] - 350:.1f}" y="{ys[3] - 60:.1f}" type="priority"/>',
              f'    <node id="r_off2" x="{xs[5] + 350:.1f}" y="{ys[5] - 60:.1f}" type="priority"/>']
    v, vr = speed_kmh * KMH, ramp_kmh * KMH

    def edge(eid: str, a: str, b: str, n: int, s: float, prio: int) -> str:
        return (f'    <edge id="{eid}" from="{a}" to="{b}" numLanes="{n}" speed="{s:.2f}" priority="{prio}" '
                f'type="highway.{"motorway" if prio > 10 else "motorway_link"}" {NO_BIKES}/>')

    edges = [edge("main0", "n0", "on1", lanes, v, 13), edge("weave", "on1", "off1", lanes + 1, v, 13),
             edge("main1", "off1", "on2", lanes, v, 13), edge("accel2", "on2", "drop2", lanes + 1, v, 13),
             edge("main2", "drop2", "off2", lanes, v, 13), edge("main3", "off2", "n6", lanes, v, 13),
             edge("ramp_on1", "r_on1", "on1", 1, vr, 10), edge("ramp_off1", "off1", "r_off1", 1, vr, 10),
             edge("ramp_on2", "r_on2", "on2", 1, vr, 10), edge("ramp_off2", "off2", "r_off2", 1, vr, 10)]
    stem = net.name.split(".")[0]
    _write_plain(net.parent, stem, nodes, edges)
    _netconvert(net.parent, stem, net, ["--ramps.guess", "false", "--junctions.join", "false"])
    return {"lanes": lanes, "speed_kmh": speed_kmh, "ramp_speed_kmh": ramp_kmh, "weaving_m": round(weave),
            "acceleration_lane_m": round(accel), "length_m": round(float(xs[-1]))}


def roundabout(net: Path, k: int, seed: int) -> dict[str, Any]:
    """A roundabout (netconvert's roundabout guessing finds the one-way ring) with 3-5 arms.

    Ring: radius 14-35 m, 1-2 lanes at 25-40 km/h, counter-clockwise (right-hand traffic). Arms:
    150-350 m, 1-2 lanes each way at 50-70 km/h, each ending at a priority junction with a short
    cross road so that traffic has somewhere to come from and go to.
    """
    rng = np.random.default_rng([seed, k, 13])
    arms = int(rng.integers(3, 6))
    radius = float(rng.uniform(14, 35))
    ring_lanes = int(rng.integers(1, 3))
    ring_kmh = float(rng.uniform(25, 40))
    arm_kmh = float(rng.choice([50, 60, 70]))
    angles = np.sort(rng.uniform(0, 2 * math.pi / arms, 1) + np.arange(arms) * 2 * math.pi / arms
                     + rng.uniform(-0.25, 0.25, arms))
    nodes, edges = [], []
    for i, a in enumerate(angles):
        length = float(rng.uniform(150, 350))
        arm_lanes = int(rng.integers(1, 3))
        rx, ry = radius * math.cos(a), radius * math.sin(a)
        ox, oy = (radius + length) * math.cos(a), (radius + length) * math.sin(a)
        nodes.append(f'    <node id="r{i}" x="{rx:.2f}" y="{ry:.2f}" type="priority"/>')
        nodes.append(f'    <node id="o{i}" x="{ox:.2f}" y="{oy:.2f}" type="priority"/>')
        px, py = -math.sin(a), math.cos(a)  # the cross road at the arm's end
        for side, sgn in (("a", 1), ("b", -1)):
            nodes.append(f'    <node id="c{i}{side}" x="{ox + sgn * 200 * px:.2f}" y="{oy + sgn * 200 * py:.2f}" '
                         'type="priority"/>')
            for frm, to in ((f"o{i}", f"c{i}{side}"), (f"c{i}{side}", f"o{i}")):
                edges.append(f'    <edge id="{frm}_{to}" from="{frm}" to="{to}" numLanes="1" '
                             f'speed="{arm_kmh * KMH:.2f}" priority="5"/>')
        for frm, to in ((f"o{i}", f"r{i}"), (f"r{i}", f"o{i}")):
            edges.append(f'    <edge id="{frm}_{to}" from="{frm}" to="{to}" numLanes="{arm_lanes}" '
                         f'speed="{arm_kmh * KMH:.2f}" priority="7"/>')
    for i in range(arms):
        a0, a1 = angles[i], angles[(i + 1) % arms] + (2 * math.pi if i + 1 == arms else 0.0)
        pts = [(radius * math.cos(t), radius * math.sin(t)) for t in np.linspace(a0, a1, 8)]
        shape = " ".join(f"{x:.2f},{y:.2f}" for x, y in pts)
        edges.append(f'    <edge id="ring{i}" from="r{i}" to="r{(i + 1) % arms}" numLanes="{ring_lanes}" '
                     f'speed="{ring_kmh * KMH:.2f}" priority="9" shape="{shape}"/>')
    stem = net.name.split(".")[0]
    _write_plain(net.parent, stem, nodes, edges)
    _netconvert(net.parent, stem, net, ["--roundabouts.guess", "true", "--junctions.join", "false"])
    return {"arms": arms, "radius_m": round(radius, 1), "ring_lanes": ring_lanes,
            "ring_speed_kmh": round(ring_kmh, 1), "arm_speed_kmh": arm_kmh}


_RURAL_SPEEDS = (70 * KMH, 80 * KMH, 90 * KMH, 100 * KMH)
_URBAN_SPEEDS = tuple(s * KMH for s in (30, 40, 50, 60, 70, 80, 100))


def rural(net: Path, k: int, seed: int) -> dict[str, Any]:
    """Rural roads: a sparse random network (netgenerate), long links, 1 lane, 70-100 km/h, priority
    junctions (no traffic lights)."""
    rng = np.random.default_rng([seed, k, 17])
    speed = float(rng.choice(_RURAL_SPEEDS))
    opts = ["--rand", "--rand.iterations", str(int(rng.integers(15, 35))), "--rand.min-distance", "300",
            "--rand.max-distance", "900", "--rand.min-angle", "30", "--default.lanenumber", "1",
            "--default.speed", f"{speed:.2f}", "--default-junction-type", "priority",
            "--rand.neighbor-dist1", "0", "--rand.neighbor-dist2", "1", "--seed", str(seed * 1000 + 500 + k)]
    netgenerate(net, opts)
    return {"speed_kmh": round(speed / KMH), "netgenerate": opts}


def family(net: Path, k: int, seed: int) -> dict[str, Any]:
    """netgenerate grid / spider / random with 1-3 lanes, 30-100 km/h and every junction control
    (traffic lights, priority, right-before-left, all-way stop)."""
    kind, opts = netgenerate_options(k, seed, speeds=_URBAN_SPEEDS)
    netgenerate(net, opts)
    return {"kind": kind, "netgenerate": opts}
