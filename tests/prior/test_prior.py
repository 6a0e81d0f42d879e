from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

from coster_sumo.cli.command_line import main
from coster_sumo.data import synthetic
from coster_sumo.errors import InputError
from coster_sumo.formats.scene_file import save_scene
from coster_sumo.prior.bins import ATTRIBUTES, AttributeBins
from coster_sumo.prior.data import at_prior_rate, batch_tokens, epoch_samples, prepare_scene, scene_tokens
from coster_sumo.prior.evaluate import mmd, reliability
from coster_sumo.prior.infer import (
    DENSITY_OFFSET_LIMIT,
    load_prior,
    predict_scene,
    predict_tokens,
    probe_class_weights,
    probe_visible_traffic,
    read_checkpoint,
    save_prior,
)
from coster_sumo.prior.model import PriorConfig, TrafficPrior
from coster_sumo.prior.records import PriorTrainMetrics
from coster_sumo.prior.train import TrainConfig, train_prior
from tests.conftest import WOMD_PKL, WOMD_PROTO, requires_womd

SMALL = PriorConfig(hidden=64, head_hidden=64, num_blocks=2)


@pytest.fixture(autouse=True)
def single_thread():
    # tiny models: one thread avoids OpenMP contention on a busy 2-core machine (40x slower otherwise)
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def prepared():
    scenes = [synthetic.two_lane_road(), synthetic.four_way_junction(), synthetic.merge()]
    return [prepare_scene(at_prior_rate(s)) for s in scenes]


def test_bins_round_trip():
    bins = AttributeBins()
    for a in ATTRIBUTES:
        c = bins.centres(a)
        assert len(c) == bins.num_classes()[a]
    pos = bins.position_centres()
    np.testing.assert_array_equal(bins.position_class(pos), np.arange(1600))
    np.testing.assert_array_equal(bins.heading_class(bins.heading_centres()), np.arange(144))
    np.testing.assert_array_equal(bins.speed_class(bins.speed_centres()), np.arange(61))
    assert bins.speed_class(np.array([0.0, 0.49, 0.51, 45.0])).tolist() == [0, 0, 1, 60]
    np.testing.assert_array_equal(bins.length_class(bins.length_centres()), np.arange(60))
    assert bins.width_class(np.array([-1.0, 9.0])).tolist() == [0, 39]


def test_hidden_regions_carry_no_agent_information(prepared):
    cfg = PriorConfig()
    rng = np.random.default_rng(0)
    samples = epoch_samples(prepared, rng)
    tok = batch_tokens(prepared, samples, cfg, visible="random", rng=rng)
    assert tok.map_features.shape[:2] == tok.mask.shape and tok.map_features.shape[2] == cfg.map_features
    assert np.all(tok.agent_features[tok.query] == 0.0)
    assert np.all(tok.query <= tok.mask) and np.all(tok.present <= tok.mask)
    assert tok.query.any() and (tok.mask & ~tok.query).any()
    # each agent occupies at most one token per sample, so hiding it hides it everywhere
    for b in range(len(samples)):
        d = prepared[samples[b, 0]]
        t = d.centres[samples[b, 1], 0]
        agent, _, _ = d.occupancy.gather(t, np.maximum(tok.region_index[b], 0))
        agent = agent[tok.present[b]]
        assert len(agent) == len(np.unique(agent))
    # the centre vehicle is in its own neighbourhood
    assert tok.present.any(axis=1).all()


def test_map_mode_hides_everything_and_context_mode_only_nearby(prepared):
    cfg = PriorConfig()
    d = prepared[1]  # the junction
    rows = np.flatnonzero(d.centres[:, 0] == 5)
    tok_map = scene_tokens(d, d.centres[rows, 0], d.centre_pose[rows], cfg)
    assert np.array_equal(tok_map.query, tok_map.mask)
    tok_ctx = scene_tokens(d, d.centres[rows, 0], d.centre_pose[rows], cfg,
                           visible="context", hide_radius=10.0)
    centre = d.regions.centre[np.maximum(tok_ctx.region_index, 0)]
    dist = np.linalg.norm(centre - d.centre_pose[rows, None, :2], axis=-1)
    assert np.array_equal(tok_ctx.query, tok_ctx.mask & (dist <= 10.0))


def test_loss_decreases_and_model_overfits_one_batch(prepared):
    # float64: in float32 the 300 Adam steps are chaotic in the last bits, so which basin the fit
    # ends in depended on the CPU's float kernels (presence accuracy 1.0 with ATen's AVX2 kernels,
    # 0.98 with its AVX-512 ones on the same machine, 0.96 on an Intel AVX-512 machine). In float64
    # the AVX2, AVX-512 and generic kernels end within 1e-7 of one another's loss and every hidden
    # token's presence is at least 0.46 from the 0.5 threshold.
    torch.manual_seed(0)
    model = TrafficPrior(dataclasses.replace(SMALL, num_blocks=5)).double()
    rng = np.random.default_rng(1)
    samples = epoch_samples(prepared, rng)[:3]
    tok = batch_tokens(prepared, samples, SMALL, visible="random", rng=rng)
    batch = [torch.from_numpy(a) for a in (tok.map_features, tok.agent_features, tok.mask, tok.query,
                                            tok.present, tok.classes)]
    batch = [b.double() if b.is_floating_point() else b for b in batch]
    steps = 300
    opt = torch.optim.Adam(model.parameters(), lr=5e-3)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)  # smooth convergence, no late spikes
    losses = []
    for _ in range(steps):
        _, loss = model(*batch)
        assert loss is not None
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        losses.append(float(loss.detach()))
    assert losses[-1] < 0.25 * losses[0]
    model.float().eval()
    presence, probs = predict_tokens(model, tok)
    q = tok.query & tok.mask
    assert np.mean((presence[q] > 0.5) == tok.present[q]) >= 0.98
    hit = q & tok.present
    for i, a in enumerate(ATTRIBUTES):
        acc = np.mean(np.argmax(probs[a][hit], -1) == tok.classes[hit][:, i])
        assert acc > 0.9, a


def test_checkpoint_round_trip(tmp_path, prepared):
    torch.manual_seed(0)
    model = TrafficPrior(SMALL).eval()
    path = save_prior(model, tmp_path / "prior.pt", metrics={"x": 1.0})
    raw = torch.load(path, weights_only=True)
    assert raw["config"]["hidden"] == 64 and raw["metrics"] == {"x": 1.0}
    loaded = load_prior(path)
    assert loaded.config == model.config
    tok = scene_tokens(prepared[0], np.array([3]), prepared[0].centre_pose[:1], SMALL)
    p0, a0 = predict_tokens(model, tok)
    p1, a1 = predict_tokens(loaded, tok)
    np.testing.assert_array_equal(p0, p1)
    for a in ATTRIBUTES:
        np.testing.assert_array_equal(a0[a], a1[a])


def test_bad_checkpoint_is_one_clear_line(tmp_path, capsys):
    with pytest.raises(InputError, match="missing.pt: no such file"):
        load_prior(tmp_path / "missing.pt")
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(InputError, match="not a readable prior checkpoint"):
        read_checkpoint(junk)
    other = tmp_path / "other.pt"
    torch.save({"state_dict": {}}, other)
    with pytest.raises(InputError, match="not a coster-sumo prior checkpoint"):
        read_checkpoint(other)
    code = main(["eval", "prior", "--data", str(tmp_path), "--checkpoint", str(tmp_path / "missing.pt"),
                 "--json", str(tmp_path / "out.json")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "missing.pt" in err[0]


def test_predict_scene_batched_over_steps():
    torch.manual_seed(0)
    model = TrafficPrior(SMALL).eval()
    scene = synthetic.four_way_junction()
    pred = predict_scene(model, scene, target=0)
    T = 19  # 91 steps at 10 Hz -> 2 Hz
    assert pred.presence.shape == pred.mask.shape and pred.mask.shape[0] == T
    assert pred.probs["position"].shape == pred.mask.shape + (1600,)
    np.testing.assert_allclose(pred.probs["heading"].sum(-1)[pred.query], 1.0, rtol=1e-5)
    assert np.all(pred.probs["heading"][~pred.query] == 0)
    assert np.all(pred.query <= pred.mask) and np.all(pred.presence[~pred.query] == 0)
    # context mode: exactly the regions within the hide radius are predicted
    centre = pred.regions.centre[np.maximum(pred.region_index, 0)]
    target_xy = at_prior_rate(scene).tracks.xy[0][:, None, :]
    near = np.linalg.norm(centre - target_xy, axis=-1) <= model.config.hide_radius
    assert np.array_equal(pred.query, pred.mask & near)
    # the target sits in one of its own neighbourhood's regions at every step
    assert np.all(np.any(pred.observed_agent == 0, axis=1))
    rng = np.random.default_rng(0)
    t, k = np.nonzero(pred.query)
    s = pred.sample(rng, t[:50], k[:50])
    assert s["world_xy"].shape == (50, 2)
    lp = pred.position_log_prob(s["world_xy"], t[:50], k[:50])
    assert np.all(np.isfinite(lp))
    assert np.all(np.isneginf(pred.position_log_prob(s["world_xy"] + 100.0, t[:50], k[:50])))
    # one step alone gives the same numbers as the batch (the density offset is fitted over the
    # steps given, so it is left out of this comparison)
    one = predict_scene(model, scene, target=0, steps=np.array([7]), calibrate=False)
    batch = predict_scene(model, scene, target=0, calibrate=False)
    kk = one.mask.shape[1]
    np.testing.assert_allclose(one.presence[0], batch.presence[7, :kk], atol=1e-5)
    full = predict_scene(model, scene, target=0, mode="map")
    assert np.array_equal(full.query, full.mask)


def _shifted_prior(bias: float) -> TrafficPrior:
    """A random prior whose presence logits are all shifted by ``bias`` (it thinks the roads are
    empty, or full)."""
    torch.manual_seed(0)
    model = TrafficPrior(SMALL).eval()
    with torch.no_grad():
        model.presence_head[-1].bias.add_(bias)
    return model


@pytest.mark.parametrize("bias", [-3.0, 3.0])
def test_density_offset_brings_the_hidden_count_to_the_traffic_around(bias):
    scene = synthetic.two_lane_road()
    model = _shifted_prior(bias)
    raw = predict_scene(model, scene, target=0, calibrate=False)
    cal = predict_scene(model, scene, target=0)
    assert raw.density_offset == 0.0 and np.sign(cal.density_offset) == -np.sign(bias)
    observed = int(np.sum(raw.query & (raw.observed_agent >= 0)))
    assert observed > 0
    assert abs(cal.presence.sum() - observed) < abs(raw.presence.sum() - observed)
    # one offset for every region: the order of the regions by presence (the snapshot's order) is kept
    q = raw.query
    assert np.array_equal(np.argsort(-raw.presence[q], kind="stable"), np.argsort(-cal.presence[q], kind="stable"))
    assert np.all(cal.presence[~q] == 0.0)
    # map mode has no traffic to read: no offset
    full, full_raw = predict_scene(model, scene, target=0, mode="map"), predict_scene(model, scene, 0, mode="map",
                                                                                     calibrate=False)
    assert full.density_offset == 0.0 and np.array_equal(full.presence, full_raw.presence)


def test_adaptation_moves_the_length_classes_towards_the_vehicles_around():
    scene = synthetic.two_lane_road()  # every vehicle is 4.5 m long
    model = _shifted_prior(0.0)  # random weights: lengths spread over every class
    raw = predict_scene(model, scene, target=0, calibrate=False)
    cal = predict_scene(model, scene, target=0)
    observed = int(AttributeBins().length_class(np.array([4.5]))[0])
    w = cal.adaptation.class_weights["length"]
    assert cal.adaptation.observed > 0 and w[observed] == w.max() and w[observed] > 1.0
    q = raw.query
    assert cal.probs["length"][q][:, observed].mean() > 2.0 * raw.probs["length"][q][:, observed].mean()
    np.testing.assert_allclose(cal.probs["length"][q].sum(-1), 1.0, rtol=1e-5)
    np.testing.assert_allclose(cal.probs["width"][q].sum(-1), 1.0, rtol=1e-5)  # the marginal follows
    # the heads that are not adapted are left as they were
    np.testing.assert_array_equal(cal.probs["heading"], raw.probs["heading"])


def test_length_evidence_counts_each_vehicle_once():
    scene = at_prior_rate(synthetic.two_lane_road())
    model = _shifted_prior(0.0)
    data = prepare_scene(scene, radius=model.config.radius)
    steps = np.arange(data.num_steps)
    pose = np.stack([scene.tracks.x[0], scene.tracks.y[0], scene.tracks.heading[0]], -1)
    cfg = model.config
    tokens = scene_tokens(data, steps, pose, cfg, visible="context",
                          hide_radius=cfg.hide_radius)
    probe = probe_visible_traffic(model, data, steps, pose, tokens)
    assert probe is not None and probe.observed > probe.vehicles > 0  # the same vehicles at several steps
    for a in ("speed", "length"):
        # per token: one count per sighting; per vehicle: one unit per distinct vehicle
        assert probe.class_counts[a].sum() == probe.observed
        np.testing.assert_allclose(probe.vehicle_counts[a].sum(), probe.vehicles)
        np.testing.assert_allclose(probe.vehicle_mass[a].sum(), probe.vehicles, rtol=1e-5)
    # every vehicle of the road is 4.5 m long: all its evidence sits in that class, in either unit
    observed = int(AttributeBins().length_class(np.array([4.5]))[0])
    assert probe.vehicle_counts["length"][observed] == pytest.approx(probe.vehicles)
    w_vehicle = probe_class_weights(probe, "length", 1.0, "vehicle")
    w_step = probe_class_weights(probe, "length", 1.0, "step")
    assert w_vehicle.argmax() == w_step.argmax() == observed
    with pytest.raises(ValueError, match="evidence"):
        probe_class_weights(probe, "length", 1.0, "token")


def test_density_offset_without_traffic_around_is_bounded():
    scene = synthetic.two_lane_road()
    tracks = dataclasses.replace(scene.tracks, valid=scene.tracks.valid & (np.arange(4) == 0)[:, None])
    pred = predict_scene(_shifted_prior(0.0), dataclasses.replace(scene, tracks=tracks), target=0)
    # nothing beyond the disc: the offset lowers presence, but the pseudo-count keeps it finite
    assert -DENSITY_OFFSET_LIMIT < pred.density_offset < 0.0
    assert np.all(pred.presence[pred.query] > 0.0)


def test_unbiased_mmd_does_not_reward_drawing_more_samples():
    rng = np.random.default_rng(0)
    # the same distribution, few samples against many: the biased estimate grows as the sample
    # shrinks (its diagonal terms), the unbiased one stays about 0
    small = [mmd(rng.normal(size=(3, 2)), rng.normal(size=(40, 2))) for _ in range(200)]
    large = [mmd(rng.normal(size=(40, 2)), rng.normal(size=(40, 2))) for _ in range(200)]
    assert np.mean(small) > 4.0 * np.mean(large)
    small_u = [mmd(rng.normal(size=(3, 2)), rng.normal(size=(40, 2)), unbiased=True) for _ in range(200)]
    assert abs(np.mean(small_u)) < 0.02
    x = rng.normal(size=(50, 2))
    assert mmd(x, x + 3.0, unbiased=True) > 0.3
    with pytest.raises(ValueError):
        mmd(x[:1], x, unbiased=True)


def test_mmd_and_reliability():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(200, 2))
    assert mmd(x, x) == pytest.approx(0.0, abs=1e-12)
    assert mmd(x, x + 3.0) > 0.3
    assert mmd(x, rng.normal(size=(200, 2))) < 0.05
    p = rng.random(20000)
    r = reliability(p, rng.random(20000) < p)
    assert r.ece is not None and r.ece < 0.02 and len(r.bins) == 10 and r.auc is not None and r.auc > 0.7


def _tiny_dataset(root):
    (root / "scenes").mkdir(parents=True)
    for i in range(3):
        origin = (100.0 * i, -50.0 * i)
        for s in (synthetic.two_lane_road(origin), synthetic.four_way_junction(origin), synthetic.merge(origin)):
            name = f"{s.scenario_id}_{i}"
            save_scene(dataclasses.replace(s, scenario_id=name), root / "scenes" / f"{name}.npz")
    return root


class StopTraining(Exception):
    """Raised from the training log: the run stops as a killed one would, after its state is saved."""


def stop_after_epoch(epoch: int):  # type: ignore[no-untyped-def]
    """A ``log`` for :func:`train_prior` that stops the run once epoch ``epoch`` is written."""

    def log(msg: str) -> None:
        if msg.startswith(f"epoch {epoch}/"):
            raise StopTraining

    return log


def test_training_is_deterministic_and_resumes(tmp_path, prepared):
    tcfg = TrainConfig(epochs=3, batch_size=8, warmup_steps=2)

    def run(name: str, log=None) -> PriorTrainMetrics:
        return train_prior(prepared[:2], prepared[2:], tmp_path / name, model_config=SMALL, train_config=tcfg,
                           progress=False, log=log)

    run("a.pt")
    with pytest.raises(StopTraining):
        run("b.pt", stop_after_epoch(2))
    assert not (tmp_path / "b.pt").exists() and (tmp_path / "b.pt.state").exists()
    metrics = run("b.pt")
    a = torch.load(tmp_path / "a.pt", weights_only=True)["state_dict"]
    b = torch.load(tmp_path / "b.pt", weights_only=True)["state_dict"]
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert len(metrics.history) == 3 and metrics.history[-1].val is not None
    saved = json.loads((tmp_path / "b.json").read_text())
    assert saved["best_epoch"] == metrics.best_epoch


def test_training_resumes_on_another_thread_count_and_names_what_stops_a_resume(tmp_path, prepared):
    threads = torch.get_num_threads()
    lines: list[str] = []

    def run(tcfg: TrainConfig, stop: int | None = None) -> PriorTrainMetrics:
        log = stop_after_epoch(stop) if stop else lines.append
        return train_prior(prepared[:2], prepared[2:], tmp_path / "p.pt", model_config=SMALL, train_config=tcfg,
                           progress=False, log=log)

    try:
        with pytest.raises(StopTraining):
            run(TrainConfig(epochs=2, batch_size=8, warmup_steps=2, threads=1), stop=1)
        metrics = run(TrainConfig(epochs=2, batch_size=8, warmup_steps=2, threads=2))
        assert len(metrics.history) == 2
        assert any(line.startswith("resuming from") and "after epoch 1" in line for line in lines), lines
        lines.clear()
        run(TrainConfig(epochs=2, batch_size=8, warmup_steps=2, threads=2, lr=0.01))
        ignored = [line for line in lines if line.startswith("ignoring")]
        assert len(ignored) == 1 and "(lr)" in ignored[0], lines
    finally:
        torch.set_num_threads(threads)


def test_training_device_cpu_and_auto_without_a_gpu_give_the_same_weights(tmp_path, prepared):
    tcfg = TrainConfig(epochs=1, batch_size=8, warmup_steps=2)
    for name, device in (("a.pt", "cpu"), ("b.pt", "cpu" if torch.cuda.is_available() else "auto")):
        metrics = train_prior(prepared[:2], prepared[2:], tmp_path / name, model_config=SMALL, train_config=tcfg,
                              progress=False, log=None, device=device)
        assert metrics.device == "cpu"
        assert torch.backends.cpu.get_cpu_capability() in metrics.cpu  # what the card's hardware line needs
    a = torch.load(tmp_path / "a.pt", weights_only=True)["state_dict"]
    b = torch.load(tmp_path / "b.pt", weights_only=True)["state_dict"]
    assert all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.parametrize("device", ["cuda", "tpu"])
def test_train_prior_on_a_device_that_is_not_there_is_one_line(tmp_path, capsys, device):
    if device == "cuda" and torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    assert main(["-q", "train", "prior", "--data", str(tmp_path / "nothing"), "--device", device,
                 "-o", str(tmp_path / "p.pt")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"--device {device}" in err[0], err


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU (run it on a lent one)")
def test_prior_trained_on_a_gpu_loads_on_the_cpu_and_resumes_there(tmp_path, prepared):
    """On a lent GPU: the prior trains there, its checkpoint loads on the CPU, and its state resumes
    on the CPU."""
    tcfg = TrainConfig(epochs=2, batch_size=8, warmup_steps=2)
    with pytest.raises(StopTraining):
        train_prior(prepared[:2], prepared[2:], tmp_path / "g.pt", model_config=SMALL, train_config=tcfg,
                    progress=False, log=stop_after_epoch(1), device="cuda")
    metrics = train_prior(prepared[:2], prepared[2:], tmp_path / "g.pt", model_config=SMALL, train_config=tcfg,
                          progress=False, log=None, device="cpu")
    assert len(metrics.history) == 2
    model = load_prior(tmp_path / "g.pt")
    assert all(p.device.type == "cpu" for p in model.parameters())


@pytest.mark.slow
def test_cli_train_then_eval(tmp_path):
    data = _tiny_dataset(tmp_path / "ds")
    out = tmp_path / "prior.pt"
    assert main(["-q", "train", "prior", "--data", str(data), "--epochs", "1", "--hidden", "16",
                 "--blocks", "1", "-o", str(out)]) == 0
    assert out.exists() and out.with_suffix(".json").exists()
    res = tmp_path / "eval.json"
    assert main(["-q", "eval", "prior", "--data", str(data), "--checkpoint", str(out), "--split", "all",
                 "--json", str(res)]) == 0
    r = json.loads(res.read_text())
    assert set(r["mmd"]) == {"prior", "mean_value", "gmm"}
    assert r["num_scenes"] == 9 and "prior_map" in r["presence"]
    hidden = r["agents_in_hidden_disc"]  # the context mode's count, the traffic beyond the disc given
    assert hidden["ground_truth"] > 0 and hidden["prior_context"] >= 0
    assert hidden["ground_truth"] < r["agents_per_scene"]["ground_truth"]  # the disc is part of the neighbourhood
    assert set(r["mmd_hidden_disc"]) == {"prior", "prior_raw", "mean_value", "gmm"}
    # the centre agent is in the disc at every step: without it the disc holds fewer agents
    w = r["without_centre_agent"]
    assert 0 <= w["agents_in_hidden_disc"]["ground_truth"] < hidden["ground_truth"]
    assert w["agents_per_scene"]["ground_truth"] < r["agents_per_scene"]["ground_truth"]
    assert set(w["mmd_hidden_disc"]) == set(r["mmd_hidden_disc"]) and set(w["mmd"]) == set(r["mmd"])
    assert main(["-q", "eval", "prior", "--data", str(data), "--checkpoint", str(out), "--split", "all",
                 "--mmd", "unbiased", "--json", str(res)]) == 0
    u = json.loads(res.read_text())
    assert u["mmd_estimator"] == "unbiased" and r["mmd_estimator"] == "biased"
    assert len({m["scenes"] for m in u["mmd"].values()}) == 1  # every method on the same scenes
    assert all(r["mmd_hidden_disc"][m]["scenes"] > 0 for m in r["mmd_hidden_disc"])


def test_target_never_valid_gives_empty_prediction():
    torch.manual_seed(0)
    model = TrafficPrior(SMALL).eval()
    scene = synthetic.two_lane_road()
    tracks = dataclasses.replace(scene.tracks, valid=scene.tracks.valid & (np.arange(4) != 0)[:, None])
    pred = predict_scene(model, dataclasses.replace(scene, tracks=tracks), target=0)
    assert pred.mask.shape[0] == 19 and not pred.mask.any() and not pred.query.any()


@pytest.mark.realdata
@requires_womd()
def test_prior_runs_on_real_womd_scenes(tmp_path):
    from coster_sumo.converters.read import read_scenes

    torch.manual_seed(0)
    ckpt = save_prior(TrafficPrior(SMALL).eval(), tmp_path / "prior.pt")
    path = (WOMD_PROTO or WOMD_PKL)[0]
    scene = read_scenes(path)[0]
    pred = predict_scene(load_prior(ckpt), scene, target=scene.sdc_index)
    assert pred.mask.shape[0] == at_prior_rate(scene).num_steps and pred.query.any()


@pytest.mark.slow
@pytest.mark.realdata
@requires_womd()
def test_eval_prior_on_a_womd_file(tmp_path):
    torch.manual_seed(0)
    ckpt = save_prior(TrafficPrior(SMALL).eval(), tmp_path / "prior.pt")
    path = (WOMD_PROTO or WOMD_PKL)[0]
    out = tmp_path / "eval.json"
    assert main(["-q", "eval", "prior", "--data", str(path), "--checkpoint", str(ckpt), "--json", str(out)]) == 0
    r = json.loads(out.read_text())
    assert r["num_scenes"] >= 1 and r["mmd"]["prior"]["scenes"] >= 0 and r["baselines_fitted_on"] is None


def test_width_is_drawn_given_the_length():
    from coster_sumo.prior.infer import draw_classes

    rng = np.random.default_rng(0)
    n, lengths, widths = 4000, 6, 5
    rows = {a: np.ones((n, 3)) for a in ATTRIBUTES}
    rows["length"] = np.ones((n, lengths))
    rows["width"] = np.ones((n, widths))
    table = np.full((lengths, widths), -1e9)
    table[np.arange(lengths), np.arange(lengths) % widths] = 0.0  # length class l has width class l % 5
    out = draw_classes(rows, rng, table, np.zeros((n, widths)))
    assert np.array_equal(out["width"], out["length"] % widths)
    free = draw_classes(rows, np.random.default_rng(0))  # independent heads: any pair
    assert np.mean(free["width"] == free["length"] % widths) < 0.5


def _long_and_short_widths(prepared, joint: bool) -> tuple[float, float]:
    """Train on data whose width is fixed by the length: every token twice, once long-and-wide and once
    short-and-narrow; the share of sampled long vehicles that are wide and of short ones that are narrow."""
    torch.manual_seed(0)
    cfg = dataclasses.replace(SMALL, label_smoothing=0.0, width_given_length=joint)  # no floor to blur it
    model = TrafficPrior(cfg)
    assert (model.width_table is not None) == joint
    bins = cfg.bins()
    tok = batch_tokens(prepared, epoch_samples(prepared, np.random.default_rng(0), 1)[:8], cfg, visible="map")
    cls = np.concatenate([tok.classes, tok.classes])
    long_ = np.arange(len(cls)) < len(tok.classes)
    cls[..., 3] = np.where(long_[:, None], bins.length_class(12.0), bins.length_class(2.2))
    cls[..., 4] = np.where(long_[:, None], bins.width_class(2.55), bins.width_class(0.8))
    batch = [torch.from_numpy(np.concatenate([x, x])) for x in (tok.map_features, tok.agent_features, tok.mask,
                                                                tok.query, tok.present)]
    batch.append(torch.from_numpy(cls))
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)
    for _ in range(300):
        _, loss = model(*batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
    model.eval()
    _, probs = predict_tokens(model, tok)
    assert ("width_logits" in probs) == joint
    np.testing.assert_allclose(probs["width"][tok.mask].sum(-1), 1.0, atol=1e-5)  # a distribution either way
    pred = predict_scene(model, prepared[0], prepared[0].sdc_index, steps=np.array([3]), mode="map")
    t, k = np.nonzero(pred.query)
    s = pred.sample(np.random.default_rng(0), np.repeat(t, 20), np.repeat(k, 20))
    long_cls = bins.length_class(s["length"]) == bins.length_class(12.0)
    short_cls = bins.length_class(s["length"]) == bins.length_class(2.2)
    assert long_cls.sum() >= 10 and short_cls.sum() >= 10
    return float(np.mean(s["width"][long_cls] > 2.0)), float(np.mean(s["width"][short_cls] < 1.2))


def test_width_given_length_is_learned_and_sampled_jointly(prepared):
    joint = _long_and_short_widths(prepared, joint=True)
    independent = _long_and_short_widths(prepared, joint=False)
    assert min(joint) > 0.9  # long vehicles come out wide, short ones narrow
    assert min(independent) < 0.75  # independent heads mix them


def test_checkpoint_from_before_speed_limits_and_joint_size_still_loads(tmp_path, prepared):
    from coster_sumo.prior.features import MAP_FEATURES, MAP_FEATURES_V1

    old = dataclasses.replace(SMALL, map_features=MAP_FEATURES_V1, max_speed=30.0, width_given_length=False)
    torch.manual_seed(0)
    model = TrafficPrior(old).eval()
    path = save_prior(model, tmp_path / "old.pt")
    ckpt = torch.load(path, weights_only=True)
    del ckpt["config"]["width_given_length"]  # what a checkpoint from before the field stores
    torch.save(ckpt, path)
    loaded = load_prior(path)
    assert loaded.config == old and loaded.width_table is None
    tok = scene_tokens(prepared[0], np.array([3]), prepared[0].centre_pose[:1], old)
    assert tok.map_features.shape[-1] == MAP_FEATURES
    presence, probs = predict_tokens(loaded, tok)  # reads the first 17 map features only
    assert "width_logits" not in probs and np.isfinite(presence).all()


def test_map_features_carry_the_lane_speed_limit(prepared):
    from coster_sumo.prior.features import SPEED_LIMIT, SPEED_LIMIT_KNOWN, SPEED_LIMIT_SCALE

    data = prepared[0]
    tok = scene_tokens(data, np.array([3]), data.centre_pose[:1], SMALL)
    m = tok.mask
    limit = data.regions.speed_limit[tok.region_index[m]]
    assert (limit > 0).all()
    np.testing.assert_allclose(tok.map_features[m][:, SPEED_LIMIT], limit / SPEED_LIMIT_SCALE, rtol=1e-6)
    assert (tok.map_features[m][:, SPEED_LIMIT_KNOWN] == 1).all()


def test_sampled_speeds_fill_their_bins():
    bins = AttributeBins()
    rng = np.random.default_rng(0)
    classes = rng.integers(0, bins.speed_bins + 1, 5000)
    v = bins.speed_in_bin(classes, rng)
    assert np.all(v[classes == 0] == 0.0)
    moving = classes > 0
    assert np.array_equal(bins.speed_class(v[moving]), classes[moving])  # each speed stays in its class
    assert len(np.unique(v[moving])) == moving.sum()  # not a comb of 60 centres
    last = classes == bins.speed_bins
    e = bins.speed_edges()
    assert v[last].min() >= e[-2] and v[last].max() <= e[-1]
