"""Log replay of converted scenes: exact positions, staging, signals from the log, plain configs."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from coster_sumo.converters.to_sumo import convert_scene

from coster_sumo.cli.command_line import main
from coster_sumo.data import synthetic
from coster_sumo.formats.scene_file import load_scene
from coster_sumo.formats.scene_folder import tls_state_strings
from coster_sumo.geometry import frames
from coster_sumo.sim.record import record
from coster_sumo.sim.replay import LogReplayer, ReplayOptions, replay
from coster_sumo.sim.session import SumoSession
from tests.conftest import NO_WOMD_REASON, REPO, WOMD_PKL, WOMD_PROTO

pytestmark = pytest.mark.sumo

MAX_CENTRE_ERROR_M = 0.05  # [m] acceptance


@pytest.fixture(scope="module")
def converted(tmp_path_factory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("converted")
    return {name: convert_scene(make(), out).folder for name, make in synthetic.ALL.items()}


def cfg_of(folder: Path) -> Path:
    (cfg,) = folder.glob("*.sumocfg")
    return cfg


@pytest.mark.parametrize("name", sorted(synthetic.ALL))
def test_replay_follows_the_log_exactly(converted, name):
    summary = replay(cfg_of(converted[name]))
    scene = load_scene(converted[name] / "scene.npz")
    assert summary["mode"] == "replay" and summary["steps"] == scene.num_steps
    assert summary["valid_states_compared"] == int(scene.tracks.valid.sum())
    assert summary["centre_error_max_m"] < 1e-6


@pytest.mark.parametrize("name", sorted(synthetic.ALL))
def test_recording_a_replay_leaves_out_agents_on_the_staging_lane(converted, name):
    """Agents parked on the staging lane (one step before they appear) are not in the recording."""
    cfg = cfg_of(converted[name])
    replayer = LogReplayer.for_config(cfg)
    log = replayer.scene

    def before(sess: SumoSession) -> None:
        replayer.before_step(sess, round(sess.time + sess.step_length, 9))

    with SumoSession(cfg) as sim:
        rec = record(sim, end=float(log.timestamps[-1]), before_step=before)
    assert int(rec.tracks.valid.sum()) == int(log.tracks.valid.sum())
    lo = np.array([log.tracks.x[log.tracks.valid].min(), log.tracks.y[log.tracks.valid].min()]) - 1.0
    hi = np.array([log.tracks.x[log.tracks.valid].max(), log.tracks.y[log.tracks.valid].max()]) + 1.0
    xy = np.stack([rec.tracks.x[rec.tracks.valid], rec.tracks.y[rec.tracks.valid]], axis=-1)
    assert ((xy >= lo) & (xy <= hi)).all()  # the staging lane lies 1 km below the map


def test_fcd_output_rows_are_the_log_one_step_earlier(converted, tmp_path):
    folder = converted["four_way_junction"]
    fcd = tmp_path / "fcd.xml"
    summary = replay(cfg_of(folder), ReplayOptions(fcd_output=fcd))
    assert summary["centre_error_max_m"] < 1e-6
    scene = load_scene(folder / "scene.npz")
    tr = scene.tracks
    dt = round(scene.dt, 6)
    rows = {}
    for ts in ET.parse(fcd).getroot().iter("timestep"):
        for v in ts.iter("vehicle"):
            rows[(round(float(ts.get("time", "0")), 3), v.get("id"))] = (float(v.get("x", "0")),
                                                                          float(v.get("y", "0")))
    a = tr.index_of("sdc")
    for k in (0, 45, 90):
        fx, fy = frames.centre_to_front(tr.x[a, k], tr.y[a, k], tr.heading[a, k], 4.5)
        x, y = rows[(round(float(scene.timestamps[k]) - dt, 3), "sdc")]
        assert (x, y) == pytest.approx((float(fx), float(fy)), abs=1e-3)
    # the late vehicle (valid from step 20) was staged far below the map, never in the junction
    late_rows = sorted(t for (t, vid) in rows if vid == "late")
    assert late_rows[0] == pytest.approx(float(scene.timestamps[20]) - 2 * dt)


def test_signals_follow_the_log(converted):
    folder = converted["four_way_junction"]
    replayer = LogReplayer.for_config(cfg_of(folder))
    scene = replayer.scene
    lane_map = json.loads((folder / "lane_map.json").read_text())
    expected = tls_state_strings(scene, lane_map["tls"])
    (tid,) = expected
    assert set(expected[tid][0]) == {"g", "r"} and "y" in "".join(expected[tid])
    seen = {}
    with SumoSession(cfg_of(folder)) as sim:
        while sim.time < scene.timestamps[-1] - 1e-6:
            replayer.before_step(sim, round(sim.time + replayer.dt, 9))
            sim.step()
            k = replayer.step_at(sim.time)
            if k is not None:
                seen[k] = sim.tls_state(tid)
    assert [seen[k] for k in sorted(seen)] == expected[tid]


def test_replay_cli_writes_summary(converted, tmp_path, capsys):
    cfg = cfg_of(converted["merge"])
    rc = main(["-q", "replay", str(cfg), "--end", "3.0", "--fcd-output", str(tmp_path / "f.xml"),
               "-o", str(tmp_path / "r")])
    assert rc == 0
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert summary["end_s"] == pytest.approx(3.0) and summary["centre_error_max_m"] < 1e-6
    assert (tmp_path / "f.xml").is_file()
    capsys.readouterr()


def test_replay_runs_a_plain_config(tmp_path):
    cfgs = sorted((REPO / "networks").glob("*/*.sumocfg"))
    if not cfgs:
        pytest.skip("no shipped networks")
    summary = replay(cfgs[0], ReplayOptions(end=5.0, fcd_output=tmp_path / "fcd.xml"))
    assert summary["mode"] == "run" and summary["end_s"] == pytest.approx(5.0)
    assert (tmp_path / "fcd.xml").stat().st_size > 0


def test_replay_missing_config_is_one_line(tmp_path, capsys):
    assert main(["replay", str(tmp_path / "nope.sumocfg")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nope.sumocfg" in err


REAL = [*WOMD_PROTO, *WOMD_PKL]


@pytest.mark.realdata
@pytest.mark.slow
@pytest.mark.skipif(not REAL, reason=NO_WOMD_REASON)
def test_real_scenes_replay_within_acceptance(tmp_path, capsys):
    assert main(["-q", "convert", *map(str, REAL), "-o", str(tmp_path)]) == 0
    folders = sorted(p for p in tmp_path.iterdir() if p.is_dir())
    assert len(folders) == 4
    for folder in folders:
        summary = replay(cfg_of(folder), ReplayOptions(fcd_output=tmp_path / f"{folder.name}.fcd.xml"))
        assert summary["valid_states_compared"] > 1000, folder.name
        assert summary["centre_error_max_m"] < MAX_CENTRE_ERROR_M, folder.name
        assert np.isfinite(summary["centre_error_mean_m"])
    capsys.readouterr()
