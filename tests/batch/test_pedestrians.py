"""Pedestrians in the corpus (``corpus build --pedestrians``): guessed sidewalks and crossings,
random walks, persons recorded as PEDESTRIAN tracks; without the option the corpus is unchanged."""

from __future__ import annotations

import dataclasses
import hashlib
import math
from importlib import metadata
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from coster_sumo.batch import pedestrians
from coster_sumo.batch.corpus import CorpusConfig, catalogue, plan_corpus
from coster_sumo.cli.command_line import main
from coster_sumo.core.scene import ObjectType
from coster_sumo.data import dataset
from coster_sumo.formats.scene_file import load_scene
from coster_sumo.sim.persons import PersonReader

# Walking speeds: adults cross at about 1.2-1.5 m/s on average (Knoblauch, Pietrucha and Nitzburg,
# Transportation Research Record 1538, 1996: about 1.5 m/s younger, 1.25 m/s older pedestrians;
# docs/method.md, class limits). SUMO's persons want 1.39 m/s times a speed factor kept in 0.6-1.5.
WALK_MEDIAN_MPS = (1.0, 1.6)  # [m/s] the median moving speed lies in here
WALK_MAX_MPS = 1.39 * 1.5 + 0.01  # [m/s] no pedestrian faster than SUMO lets the fastest one walk


class _FakePersons:
    """libsumo's person domain, for a reader test without SUMO: walkers on straight lines."""

    def __init__(self) -> None:
        self.t = 0.0
        self.walkers = {"p0": (0.0, 0.0, 90.0, 1.2), "p1": (10.0, 5.0, 0.0, 1.5)}  # x, y, SUMO angle, speed

    def getIDList(self) -> list[str]:  # noqa: N802 (libsumo's name)
        return ["p0"] if self.t < 0.25 else ["p0", "p1"]

    def getPosition(self, p: str) -> tuple[float, float]:  # noqa: N802
        x, y, angle, v = self.walkers[p]
        return (x + v * self.t * math.sin(math.radians(angle)), y + v * self.t * math.cos(math.radians(angle)))

    def getAngle(self, p: str) -> float:  # noqa: N802
        return self.walkers[p][2]

    def getSpeed(self, p: str) -> float:  # noqa: N802
        return self.walkers[p][3]

    def getLength(self, p: str) -> float:  # noqa: N802
        return 0.215

    def getWidth(self, p: str) -> float:  # noqa: N802
        return 0.478


def test_person_reader_appends_walkers_as_pedestrian_tracks():
    """Persons come after the vehicles, typed PEDESTRIAN, box centre half a length behind SUMO's
    front, heading and velocity along the walking direction, valid from the step they appear."""
    persons = _FakePersons()
    session = SimpleNamespace(api=SimpleNamespace(person=persons), time=0.0)
    reader = PersonReader()
    times = []
    for k in range(1, 6):
        persons.t = session.time = 0.1 * k
        times.append(session.time)
        reader(session, None)
    base = _vehicle_scene(np.array(times))
    merged = reader.merge(base)
    tr = merged.tracks
    assert tr.num_agents == base.tracks.num_agents + 2
    assert tr.ids[-2:].tolist() == ["p0", "p1"]
    assert (tr.object_type[-2:] == ObjectType.PEDESTRIAN).all()
    assert tr.valid[-2].all() and tr.valid[-1].tolist() == [False, False, True, True, True]
    # p0 walks east (SUMO's 90 deg: yaw 0, +x) at 1.2 m/s; p1 north (SUMO's 0 deg: yaw pi/2)
    assert np.allclose(tr.heading[-2], 0.0) and np.allclose(tr.vx[-2], 1.2) and np.allclose(tr.vy[-2], 0.0)
    assert np.allclose(tr.x[-2], 1.2 * np.array(times) - 0.215 / 2)
    assert np.allclose(tr.heading[-1, 2:], math.pi / 2) and np.allclose(tr.vy[-1, 2:], 1.5)
    assert np.allclose(tr.y[-1, 2:], 5.0 + 1.5 * np.array(times[2:]) - 0.215 / 2)
    assert np.allclose(tr.length[-1, 2:], 0.215) and np.allclose(tr.width[-1, 2:], 0.478)
    assert np.array_equal(tr.x[:-2], base.tracks.x)  # the vehicles as they were
    assert reader.times == [] and reader.index == {}  # ready for the next chunk


def _vehicle_scene(timestamps: np.ndarray):  # type: ignore[no-untyped-def]
    from coster_sumo.core.scene import Lanes, RoadMap, Scene, SignalStates, Tracks

    n, t = 1, len(timestamps)
    f = {k: np.zeros((n, t)) for k in ("x", "y", "heading", "vx", "vy")}
    tracks = Tracks(ids=np.array(["car"]), object_type=np.array([int(ObjectType.VEHICLE)], np.int8),
                    length=np.full((n, t), 4.5), width=np.full((n, t), 1.8), valid=np.ones((n, t), bool), **f)
    return Scene(scenario_id="s", timestamps=timestamps, tracks=tracks, road_map=RoadMap(lanes=Lanes.empty()),
                 signals=SignalStates.empty(t), sdc_index=0, current_time_index=0, source="sumo", meta={})


def test_person_reader_refuses_a_scene_of_other_steps():
    reader = PersonReader()
    session = SimpleNamespace(api=SimpleNamespace(person=_FakePersons()), time=0.1)
    reader(session, None)
    with pytest.raises(Exception, match="persons read at 1 steps"):
        reader.merge(_vehicle_scene(np.array([0.1, 0.2])))


def test_without_pedestrians_the_plan_is_that_of_before(tmp_path):
    """The option off: no run carries a pedestrian key and the sources are the wheel's nets; on, only
    the networks given a walkable net change, and their manifest entries say so."""
    nets, _ = catalogue(tmp_path, build=False)
    off = plan_corpus(CorpusConfig(dataset=tmp_path, runs_per_network=1), nets)
    assert all("ped_density" not in t.manifest_entry() and t.ped_density == 0 for t in off)
    square = next(n for n in nets if n.name == "square")
    walk = pedestrians.Walkable(net=tmp_path / "square.walk.net.xml", additional=(), sidewalk_km=2.0,
                                guessed=True, vehicle_factor=0.5, bike_factor=0.25)
    on = plan_corpus(CorpusConfig(dataset=tmp_path, runs_per_network=1, pedestrians=True), nets, {"square": walk})
    changed = [(a, b) for a, b in zip(off, on, strict=True) if a != b]
    assert [a.run_id for a, _ in changed] == ["square_r0"]
    before, after = changed[0]
    assert after.source.path == walk.net and after.source.additional == () and square.additional
    assert after.trip_density == pytest.approx(before.trip_density * 0.5)
    assert after.bike_density == pytest.approx(before.bike_density * 0.25)
    assert after.manifest_entry()["ped_density"] == pedestrians.PED_DENSITY
    assert dataclasses.replace(after, source=before.source, trip_density=before.trip_density,
                               bike_density=before.bike_density, ped_density=0.0, sidewalk_km=0.0) == before


@pytest.mark.sumo
def test_walkable_guesses_sidewalks_crossings_and_signals_once(tmp_path):
    nets, _ = catalogue(tmp_path, build=False)
    by_name = {n.name: n for n in nets}
    assert pedestrians.walkable(by_name["highway"], tmp_path) is None  # freeways get no pedestrians
    walk = pedestrians.walkable(by_name["square"], tmp_path)
    assert walk is not None and walk.guessed and walk.sidewalk_km > 1.0
    text = walk.net.read_text()
    assert 'function="crossing"' in text and 'programID="manual"' in text  # the game's program, with crossings
    assert walk.additional == ()  # its signal file now lives in the net
    assert 0.0 < walk.vehicle_factor < 1.0  # sidewalk lanes do not count as vehicle lanes (square: 1 of 2)
    mtime = walk.net.stat().st_mtime_ns
    again = pedestrians.walkable(by_name["square"], tmp_path)
    assert again == walk and walk.net.stat().st_mtime_ns == mtime  # written once
    # a net that has sidewalks keeps them (here: the guessed one, handed in as a network)
    own = pedestrians.walkable(dataclasses.replace(by_name["square"], net=walk.net, additional=()), tmp_path)
    assert own is not None and not own.guessed and own.net == walk.net


@pytest.mark.sumo
def test_pedestrian_build_records_walkers_with_plausible_speeds(tmp_path):
    """square, 150 s, --pedestrians: the clips hold PEDESTRIAN tracks (never a clip's target), of
    SUMO's person size, walking at the speeds people walk; stats count their track time."""
    out = tmp_path / "c"
    assert main(["-q", "corpus", "build", str(out), "--pedestrians", "--runs-per-network", "1",
                 "--duration", "150", "--networks", "square", "--no-card"]) == 0
    assert (out / "nets" / "square.walk.net.xml").exists()
    speeds, tracks, ped_s = [], 0, 0.0
    for path in dataset.list_scenes(out):
        tr = load_scene(path).tracks
        ped = np.flatnonzero(tr.object_type == ObjectType.PEDESTRIAN)
        assert tr.object_type[load_scene(path).sdc_index] == ObjectType.VEHICLE
        tracks += len(ped)
        for a in ped:
            v = tr.valid[a]
            speeds += np.hypot(tr.vx[a], tr.vy[a])[v].tolist()
            assert np.allclose(tr.length[a, v], 0.215) and np.allclose(tr.width[a, v], 0.478)
            ped_s += v.sum() * 0.1
    assert tracks >= 5
    s = np.array(speeds)
    moving = s[s > 0.2]
    assert WALK_MEDIAN_MPS[0] <= np.median(moving) <= WALK_MEDIAN_MPS[1]
    assert s.max() <= WALK_MAX_MPS
    with np.load(out / "stats" / "square_r0.npz") as st:
        assert st["clip_ped_s"].sum() == pytest.approx(ped_s, rel=1e-4)
    run = dataset.read_manifest(out)["runs"][0]
    assert run["ped_density"] == pedestrians.PED_DENSITY and run["source"].endswith("square.walk.net.xml")
    from coster_sumo.batch.card import write_card

    assert f"**{ped_s / 3600:.3f} h** of pedestrian" in write_card(out).read_text()


# grid6, 150 s, seed 0, without pedestrians, recorded by main at 3579716 (before pedestrians existed)
# with SUMO 1.28.0: sha256 over every clip's name and track arrays (_tracks_digest)
_GRID6_DIGEST = "aba26768381fa106270fa6641322bc422d13868795d65d21823434357cdd7c9f"


def _tracks_digest(folder: Path) -> str:
    h = hashlib.sha256()
    for f in sorted(folder.glob("*.npz")):
        t = load_scene(f).tracks
        h.update(f.name.encode())
        for k in ("ids", "object_type", "x", "y", "heading", "vx", "vy", "length", "width", "valid"):
            h.update(np.ascontiguousarray(getattr(t, k)).tobytes())
    return h.hexdigest()


@pytest.mark.sumo
def test_without_pedestrians_the_clips_are_those_of_before(tmp_path):
    if metadata.version("eclipse-sumo") != "1.28.0":
        pytest.skip("the reference digest was recorded with SUMO 1.28.0")
    out = tmp_path / "c"
    assert main(["-q", "corpus", "build", str(out), "--runs-per-network", "1", "--duration", "150",
                 "--networks", "grid6", "--no-card"]) == 0
    assert _tracks_digest(out / "scenes") == _GRID6_DIGEST
    assert not (out / "nets" / "grid6.walk.net.xml").exists()
    assert "pedestrians" not in dataset.read_manifest(out)["corpus"]
