"""The learned rollout of pedestrian and cyclist adversaries (``models/rollout_<class>.pt``): a VRU draw
samples it when it is in the models folder, keeps the class's limits and the contact at t_col, and
falls back to the kinematic rollout, saying why, when it is not."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from coster_sumo.core.scene import resample
from coster_sumo.data import synthetic
from coster_sumo.errors import InputError
from coster_sumo.formats.scene_file import save_scene
from coster_sumo.geometry.boxes import box_signed_distance, make_boxes
from coster_sumo.geometry.drivable import DrivableArea
from coster_sumo.method.snapshot import PlacementRequest
from coster_sumo.method.vru.areas import ClassArea
from coster_sumo.method.vru.classes import CYCLIST, PEDESTRIAN, VRU_CLASSES, Kinematics
from coster_sumo.method.vru.learned import within_class, within_turn_limits
from coster_sumo.method.vru.methods import methods_for
from coster_sumo.method.vru.rollout import plan_within_limits
from coster_sumo.method.vru.snapshot import vru_snapshot
from coster_sumo.rollout.config import RolloutConfig
from coster_sumo.rollout.request import RolloutRequest
from coster_sumo.rollout.train import TrainConfig, train_rollout

TINY = {"hidden": 16, "heads": 2, "latent": 4}


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """A models folder with a tiny learned rollout of each VRU class (one short epoch on synthetic
    scenes with walkers and a rider)."""
    root = tmp_path_factory.mktemp("vru_models")
    data = root / "data"
    (data / "scenes").mkdir(parents=True)
    for name, fn in synthetic.ALL.items():
        save_scene(synthetic.with_vulnerable_road_users(fn()), data / "scenes" / f"{name}.npz")
    threads = torch.get_num_threads()
    for name in VRU_CLASSES:
        train_rollout(data, root / f"rollout_{name}.pt", RolloutConfig(agent_class=name, **TINY),
                      TrainConfig(epochs=1, batch_size=32, examples_per_epoch=64, max_val_examples=8, threads=1),
                      quiet=True, cache=False)
    torch.set_num_threads(threads)
    return root


def _draw(name: str, models_dir, rollout: str = "cvae", seed: int = 3):
    scene = synthetic.four_way_junction()
    low = resample(scene, 2.0)
    drivable = DrivableArea.from_road_map(scene.road_map)
    cls = VRU_CLASSES[name]
    area = ClassArea.build(cls, scene.road_map, drivable)
    snap = vru_snapshot(PlacementRequest(low, scene.sdc_index, np.random.default_rng(seed), drivable, "last",
                                         seed=seed), cls, area, use_prior=False, init_method="random")
    _, roll = methods_for(name, "random", rollout, area)
    result = roll.generate(RolloutRequest(low, scene.sdc_index, snap, drivable, samples=200, variants=3, seed=seed,
                                          models_dir=models_dir))
    return snap, area, result


@pytest.mark.parametrize("name", ["pedestrian", "cyclist"])
def test_a_learned_draw_keeps_the_class_limits_and_the_contact(models, name):
    cls = VRU_CLASSES[name]
    snap, area, (plans, samples, info) = _draw(name, models)
    assert info["rollout"] == f"cvae:{name}" and "rollout_note" not in info
    assert info["samples"] == 200 and info["within_limits"] >= info["in_area"] >= info["clear"] >= info["kept"]
    assert plans and samples is not None
    a, t = snap.adversary, snap.target
    for p in plans:
        assert p.vclass == cls.vclass and p.t_col == pytest.approx(snap.time)
        assert (p.x[-1], p.y[-1]) == (a.x, a.y)  # the snapshot exactly: contact at t_col
        gap = box_signed_distance(make_boxes(p.x[-1], p.y[-1], p.yaw[-1], a.length, a.width),
                                  make_boxes(t.x, t.y, t.yaw, t.length, t.width))
        assert abs(float(gap)) < 0.05
        assert plan_within_limits(p, cls)
        knots = np.stack([p.x, p.y, p.yaw], -1)[None]
        assert within_class(cls, knots)[0]
        assert not area.off_area(knots[..., :2])[0]


@pytest.mark.parametrize("name", ["pedestrian", "cyclist"])
def test_without_the_checkpoint_or_with_another_rollout_the_draw_is_kinematic_and_says_why(models, tmp_path, name):
    _, _, (plans, _, info) = _draw(name, tmp_path)  # an empty models folder
    assert info["rollout"] == f"kinematic:{name}" and f"no rollout_{name}.pt" in info["rollout_note"]
    assert plans
    _, _, (_, _, info) = _draw(name, models, rollout="cv")
    assert info["rollout"] == f"kinematic:{name}" and "--rollout cv" in info["rollout_note"]


def test_a_checkpoint_of_another_class_under_the_class_s_name_is_refused(models, tmp_path):
    (tmp_path / "rollout_pedestrian.pt").write_bytes((models / "rollout_cyclist.pt").read_bytes())
    with pytest.raises(InputError, match="a cyclist rollout checkpoint where the pedestrian's was expected"):
        _draw("pedestrian", tmp_path)


def test_samples_outside_the_limits_are_rejected_and_none_left_means_the_kinematic_rollout(models, tmp_path):
    """A pedestrian model whose decoder adds 3 m backwards to every 0.5 s step (a 6 m/s sprint):
    every sample breaks the limits, none is clipped into them, and the draw says so."""
    from coster_sumo.rollout.checkpoint import load_model, save_checkpoint

    model = load_model(models / "rollout_pedestrian.pt")
    with torch.no_grad():
        model.decoder[-1].bias[0] -= 3.0 / model.cfg.disp_scale[0]
    save_checkpoint(model, tmp_path / "rollout_pedestrian.pt")
    _, _, (plans, _, info) = _draw("pedestrian", tmp_path)
    assert info["rollout"] == "kinematic:pedestrian"
    assert "none of the 200 learned samples kept (0 within the limits" in info["rollout_note"]
    assert plans and all(plan_within_limits(p, PEDESTRIAN) for p in plans)


def _kinematics(speed_mps: float, yaw_rate: float, steps: int = 10) -> tuple[np.ndarray, Kinematics]:
    """Knots (1, steps + 1, 3) of a constant-speed, constant-turn-rate path at 2 Hz and their kinematics."""
    t = np.arange(steps + 1) * 0.5
    yaw = yaw_rate * t
    step = speed_mps * 0.5
    x = np.concatenate([[0.0], np.cumsum(step * np.cos(yaw[:-1]))])
    y = np.concatenate([[0.0], np.cumsum(step * np.sin(yaw[:-1]))])
    knots = np.stack([x, y, yaw], -1)[None]
    return knots, Kinematics.of(knots[..., :2], knots[..., 2], 0.5)


def test_turning_limits_a_pedestrian_turns_on_the_spot_a_bicycle_does_not():
    standing_turn, kin = _kinematics(0.0, 1.5)
    assert within_turn_limits(PEDESTRIAN, kin)[0] and within_class(PEDESTRIAN, standing_turn)[0]
    assert not within_turn_limits(CYCLIST, kin)[0]
    # a rider at 5 m/s on a 5 m radius: lateral acceleration 5 m/s^2, over its 3 m/s^2
    _, tight = _kinematics(5.0, 1.0)
    assert not within_turn_limits(CYCLIST, tight)[0]
    _, gentle = _kinematics(5.0, 0.3)  # 1.5 m/s^2, radius 16.7 m
    assert within_turn_limits(CYCLIST, gentle)[0]
    sprint, _ = _kinematics(6.0, 0.0)
    assert not within_class(PEDESTRIAN, sprint)[0] and within_class(CYCLIST, sprint)[0]
