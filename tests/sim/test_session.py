"""SumoSession: life cycle, input errors, bulk reads in our frame, moveToXY placement, TraCI parity."""

from __future__ import annotations

import math
import subprocess
from pathlib import Path

import numpy as np
import pytest

from coster_sumo.errors import InputError, SumoError
from coster_sumo.geometry import frames
from coster_sumo.infra import sumo_install
from coster_sumo.sim.session import RECOMMENDED_OPTIONS, SumoSession

REPO = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.sumo

# Three vehicles on a 3x3 traffic-light grid (A0..C2, 100 m blocks, 2 lanes per direction).
ROUTES = """<routes>
  <vType id="car" length="4.5" width="1.8"/>
  <vType id="bike" vClass="bicycle" length="1.8" width="0.6"/>
  <route id="north" edges="A0A1 A1A2"/>
  <route id="east" edges="A1B1 B1C1"/>
  <vehicle id="ego" type="car" route="east" depart="0"/>
  <vehicle id="v1" type="car" route="north" depart="0.5"/>
  <vehicle id="b1" type="bike" route="north" depart="2"/>
</routes>
"""


def make_grid(folder: Path) -> Path:
    """A 3x3 traffic-light grid with three vehicles; returns the .sumocfg."""
    folder.mkdir(parents=True, exist_ok=True)
    net = folder / "grid.net.xml"
    subprocess.run([sumo_install.binary("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", "100",
                    "-L", "2", "--default-junction-type", "traffic_light", "-o", str(net)],
                   check=True, capture_output=True, env=sumo_install.subprocess_env())
    (folder / "grid.rou.xml").write_text(ROUTES)
    cfg = folder / "grid.sumocfg"
    cfg.write_text('<configuration><input><net-file value="grid.net.xml"/>'
                   '<route-files value="grid.rou.xml"/></input></configuration>\n')
    return cfg


@pytest.fixture(scope="module")
def grid_cfg(tmp_path_factory) -> Path:
    return make_grid(tmp_path_factory.mktemp("grid"))


def test_start_step_close(grid_cfg):
    with SumoSession(grid_cfg, seed=3) as sim:
        assert sim.backend == "libsumo" and sim.is_running
        times = [sim.step() for _ in range(30)]
        np.testing.assert_allclose(np.diff(times), 0.1, atol=1e-9)
        assert sim.time == pytest.approx(3.0)
        assert set(sim.vehicle_ids()) == {"ego", "v1", "b1"}
        assert sim.min_expected_number() == 3
    assert not sim.is_running
    with pytest.raises(SumoError, match="not running"):
        sim.step()
    sim.close()  # twice is fine


def test_recommended_options_and_overrides(grid_cfg):
    sim = SumoSession(grid_cfg, options={"--collision.action": "remove"},
                      extra_args=["--time-to-teleport=300"])
    cmd = sim.command()
    for key in RECOMMENDED_OPTIONS:
        assert cmd.count(key) <= 1
    assert cmd[cmd.index("--collision.action") + 1] == "remove"
    assert "--time-to-teleport" not in cmd and cmd[-1] == "--time-to-teleport=300"
    assert cmd[cmd.index("--step-length") + 1] == "0.1"


def test_second_libsumo_session_raises(grid_cfg):
    with SumoSession(grid_cfg) as first:
        first.step()
        with pytest.raises(SumoError, match="one simulation per process"):
            SumoSession(grid_cfg).start()
        assert first.time == pytest.approx(0.1)  # the first one was not replaced
        first.step()
    with SumoSession(grid_cfg) as again:  # after close a new one is fine
        again.step()


@pytest.mark.parametrize("case", ["missing_cfg", "cfg_not_xml", "missing_net", "truncated_net",
                                  "missing_routes"])
def test_broken_inputs_name_the_file(tmp_path, grid_cfg, case):
    net = grid_cfg.parent / "grid.net.xml"
    cfg = tmp_path / "x.sumocfg"
    culprit = cfg
    if case == "cfg_not_xml":
        cfg.write_text("<configuration><input>")
    elif case == "missing_net":
        cfg.write_text('<configuration><input><net-file value="nope.net.xml"/></input></configuration>')
        culprit = tmp_path / "nope.net.xml"
    elif case == "truncated_net":  # would crash libsumo (segfault) if it reached SUMO
        bad = tmp_path / "cut.net.xml"
        bad.write_text(net.read_text()[:5000])
        cfg.write_text('<configuration><input><net-file value="cut.net.xml"/></input></configuration>')
        culprit = bad
    elif case == "missing_routes":
        cfg.write_text(f'<configuration><input><net-file value="{net}"/>'
                       '<route-files value="a.rou.xml,gone.rou.xml"/></input></configuration>')
        (tmp_path / "a.rou.xml").write_text("<routes/>")
        culprit = tmp_path / "gone.rou.xml"
    with pytest.raises(InputError) as info:
        SumoSession(cfg).start()
    msg = str(info.value)
    assert str(culprit) in msg and "\n" not in msg


def test_sumo_refusal_is_one_line(tmp_path, grid_cfg):
    routes = tmp_path / "bad.rou.xml"
    routes.write_text('<routes><vehicle id="x" route="no_such_route" depart="0"/></routes>')
    with pytest.raises(InputError) as info:
        SumoSession(net=grid_cfg.parent / "grid.net.xml", routes=routes).start()
    assert str(info.value).startswith(str(grid_cfg.parent / "grid.net.xml")) and "\n" not in str(info.value)
    with SumoSession(grid_cfg) as sim:  # a failed start leaves libsumo usable
        sim.step()


def test_vehicle_states_are_centres_in_our_frame(grid_cfg):
    with SumoSession(grid_cfg) as sim:
        for _ in range(60):
            sim.step()
        st = sim.vehicle_states()
        veh = sim.api.vehicle
        for i, vid in enumerate(st.ids):
            fx, fy = veh.getPosition(vid)
            length = veh.getLength(vid)
            assert st.length[i] == length and st.width[i] == veh.getWidth(vid)
            assert abs(float(frames.wrap_angle(st.yaw[i] - math.radians(90.0 - veh.getAngle(vid))))) < 1e-12
            assert fx == pytest.approx(st.x[i] + 0.5 * length * math.cos(st.yaw[i]), abs=1e-9)
            assert fy == pytest.approx(st.y[i] + 0.5 * length * math.sin(st.yaw[i]), abs=1e-9)
            assert st.speed[i] == veh.getSpeed(vid)
        assert st.vclass[st.index_of("b1")] == "bicycle"
        assert st.type_id[st.index_of("ego")] == "car"


@pytest.mark.parametrize("traci", [False, True])
def test_move_to_xy_round_trip(grid_cfg, traci):
    """Centre pose in, the same centre pose out; first placement on a lane, later ones anywhere."""
    with SumoSession(grid_cfg, traci=traci) as sim:
        sim.step()
        x0, y0 = sim.api.lane.getShape("A0A1_0")[0]
        sim.add_vehicle("adv", length=4.8, width=2.0)
        poses = [(x0, y0 + 20.0, math.pi / 2), (x0 + 0.3, y0 + 22.5, 1.4), (x0 + 3.0, y0 + 25.0, 0.2),
                 (x0 - 40.0, y0 + 30.0, -2.9), (x0 + 37.123456, y0 + 99.87654, math.pi)]
        for cx, cy, yaw in poses:
            sim.move_to_xy("adv", cx, cy, yaw)
            sim.step()
            st = sim.vehicle_states(["adv"])
            assert abs(st.x[0] - cx) < 1e-6 and abs(st.y[0] - cy) < 1e-6
            assert abs(float(frames.wrap_angle(st.yaw[0] - yaw))) < 1e-12
            assert "adv" not in sim.arrived_ids()


@pytest.mark.parametrize("given_speed", [False, True])
def test_reported_speed_is_not_capped(grid_cfg, given_speed):
    """25 m/s on a 13.89 m/s lane: SUMO would report about 14.7 without the speed-factor lift."""
    with SumoSession(grid_cfg) as sim:
        sim.step()
        x0, y0 = sim.api.lane.getShape("A0A1_0")[0]
        assert sim.api.lane.getMaxSpeed("A0A1_0") < 14.0
        sim.add_vehicle("adv", length=4.5, width=1.8)
        speeds = []
        for k in range(6):
            sim.move_to_xy("adv", x0, y0 + 10.0 + 2.5 * k, math.pi / 2, speed=25.0 if given_speed else None)
            sim.step()
            speeds.append(float(sim.vehicle_states(["adv"]).speed[0]))
        assert speeds[1:] == pytest.approx([25.0] * 5)
        if given_speed:
            assert speeds[0] == pytest.approx(25.0)


def test_sumo_collision_list(grid_cfg):
    with SumoSession(grid_cfg) as sim:
        for _ in range(40):
            sim.step()
        st = sim.vehicle_states(["ego"])
        sim.add_vehicle("adv", length=4.5, width=1.8)
        hits = []
        for _ in range(3):
            st = sim.vehicle_states(["ego"])
            sim.move_to_xy("adv", float(st.x[0]), float(st.y[0]), float(st.yaw[0]))
            sim.step()
            hits += sim.collisions()
        assert hits and {"collider", "victim", "type", "lane", "pos"} <= set(hits[0])
        assert {hits[0]["collider"], hits[0]["victim"]} == {"adv", "ego"}


def test_traffic_lights(grid_cfg):
    with SumoSession(grid_cfg) as sim:
        sim.step()
        ids = sim.tls_ids()
        assert "B1" in ids
        links = sim.tls_controlled_links("B1")
        state = sim.tls_state("B1")
        assert len(state) == len(links) and set(state) <= set("rRgGyYuoOs")
        for group in links:  # grid edge ids are "<from node><to node>": incoming lanes end at B1
            assert all(frm.split("_")[0].endswith("B1") and via.startswith(":B1_") for frm, _, via in group)
        sim.set_tls_state("B1", "r" * len(state))
        sim.step()
        assert sim.tls_states()["B1"] == "r" * len(state)


def test_traci_matches_libsumo(grid_cfg):
    runs = {}
    for traci in (False, True):
        with SumoSession(grid_cfg, seed=7, traci=traci) as sim:
            for _ in range(50):
                sim.step()
            st = sim.vehicle_states()
            order = np.argsort(st.ids)
            runs[traci] = (st.ids[order], st.x[order], st.y[order], st.yaw[order], st.speed[order])
    for a, b in zip(runs[False], runs[True], strict=True):
        np.testing.assert_array_equal(a, b)


def test_attach_to_an_external_server(grid_cfg):
    sumolib = sumo_install.import_sumolib()
    port = sumolib.miscutils.getFreeSocketPort()
    server = subprocess.Popen([sumo_install.binary("sumo"), "-c", str(grid_cfg), "--remote-port", str(port),
                               "--step-length", "0.1", "--no-step-log", "true"],
                              stdout=subprocess.DEVNULL, env=sumo_install.subprocess_env())
    try:
        with SumoSession(port=port) as sim:
            assert sim.backend == "traci"
            for _ in range(30):
                sim.step()
            assert sim.time == pytest.approx(3.0)
            assert set(sim.vehicle_ids()) == {"ego", "v1", "b1"}
        assert server.wait(timeout=10) == 0
    finally:
        if server.poll() is None:
            server.kill()


def test_vehicles_near_values_equal_the_getters():
    """States read from the context subscription of vehicles_near are what the getters say."""
    with SumoSession(REPO / "networks" / "arterial" / "arterial.sumocfg", seed=1) as sim:
        for _ in range(300):
            sim.step()
        centre = sim.vehicle_ids()[0]
        checked = 0
        for _ in range(20):
            sim.step()
            if centre not in sim.vehicle_ids():
                break
            near = sim.vehicles_near(centre, 80.0)
            fast = sim.vehicle_states(near)
            sim._near_values = {}  # force the getters
            slow = sim.vehicle_states(near)
            for f in ("x", "y", "yaw", "speed", "length", "width"):
                assert np.array_equal(getattr(fast, f), getattr(slow, f)), f
            checked += len(near) > 1
        assert checked >= 5


def test_additional_files_are_loaded_besides_the_configurations_own(tmp_path):
    """SUMO's -a replaces a configuration's additional-files. A planner's vType file (sumo:Krauss)
    dropped the demand of the wheel's square, which keeps its routes in an additional file: no
    vehicle ran in the nominal pass, and regress's variants ran without traffic."""
    import sumo

    cfg = Path(sumo.__file__).parent / "tools" / "game" / "square.sumocfg"
    if not cfg.is_file():
        pytest.skip(f"{cfg} not in this SUMO build")
    extra = tmp_path / "vtype.add.xml"
    extra.write_text('<additional><vType id="mine" carFollowModel="IDM"/></additional>\n')
    cmd = SumoSession(cfg, additional=[extra]).command()
    loaded = cmd[cmd.index("-a") + 1].split(",")
    assert loaded[-1] == str(extra) and any(p.endswith("input_additional.add.xml") for p in loaded[:-1])
    with SumoSession(cfg, additional=[extra], end=20.0) as sim:
        seen = set()
        while sim.time < 19.9:
            sim.step()
            seen.update(sim.vehicle_ids())
    assert seen, "the configuration's own demand must run"
