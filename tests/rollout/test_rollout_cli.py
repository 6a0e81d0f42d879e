"""``coster-sumo train rollout``, ``train vocab`` and ``eval rollout`` on a tiny dataset built in code."""

from __future__ import annotations

import json

import pytest
import torch

from coster_sumo.cli.command_line import main
from coster_sumo.data import synthetic
from coster_sumo.formats.scene_file import save_scene
from coster_sumo.infra import devices
from coster_sumo.rollout.checkpoint import load_model
from coster_sumo.rollout.vocab import MotionVocab

TINY = ["--hidden", "16", "--heads", "2", "--latent", "4", "--batch-size", "32", "--examples-per-epoch", "64",
        "--max-val-examples", "16"]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("rollout_data")
    (root / "scenes").mkdir()
    for name, fn in synthetic.ALL.items():
        save_scene(fn(), root / "scenes" / f"{name}.npz")
    return root


def train(dataset, out, *extra):
    return main(["-q", "train", "rollout", "--data", str(dataset), "-o", str(out), *TINY, *extra])


def test_train_resume_and_determinism(dataset, tmp_path):
    a, b = tmp_path / "a.pt", tmp_path / "b.pt"
    assert train(dataset, a, "--epochs", "1") == 0
    assert a.is_file() and (tmp_path / "a.json").is_file() and (tmp_path / "a.pt.state").is_file()
    assert train(dataset, a, "--epochs", "2") == 0  # resumes at epoch 2
    assert train(dataset, b, "--epochs", "2") == 0  # uninterrupted
    metrics = json.loads((tmp_path / "a.json").read_text())
    assert [e["epoch"] for e in metrics["epochs"]] == [1, 2]
    assert metrics["examples"]["train"] > 0 and "train_loss" in metrics["final"]
    ma, mb = load_model(a), load_model(b)
    for k, v in ma.state_dict().items():
        assert torch.equal(v, mb.state_dict()[k]), k
    # a different setting does not silently resume the old state
    assert train(dataset, a, "--epochs", "3", "--lr", "0.1") == 2


def test_resume_on_another_thread_count_goes_on_and_a_refusal_names_the_setting(dataset, tmp_path, capsys):
    """Moving a run to another machine changes its thread count: it resumes. A setting that
    changes the run is refused on one line that says which one."""
    a = tmp_path / "a.pt"
    assert train(dataset, a, "--epochs", "1", "--threads", "1") == 0
    assert train(dataset, a, "--epochs", "2", "--threads", "2") == 0
    metrics = json.loads((tmp_path / "a.json").read_text())
    assert [e["epoch"] for e in metrics["epochs"]] == [1, 2]
    assert metrics["threads"] == 2
    capsys.readouterr()
    assert train(dataset, a, "--epochs", "3", "--threads", "1", "--seed", "5", "--lr", "0.1") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "seed 0 -> 5" in err[0] and "lr 0.001 -> 0.1" in err[0], err
    assert "threads" not in err[0]


def test_device_cpu_and_auto_without_a_gpu_are_the_default_recipe(dataset, tmp_path):
    a, b = tmp_path / "a.pt", tmp_path / "b.pt"
    assert train(dataset, a, "--epochs", "1") == 0
    assert train(dataset, b, "--epochs", "1", "--device", "cpu" if torch.cuda.is_available() else "auto") == 0
    for k, v in load_model(a).state_dict().items():
        assert torch.equal(v, load_model(b).state_dict()[k]), k
    assert json.loads((tmp_path / "b.json").read_text())["device"] == "cpu"


@pytest.mark.parametrize("device", ["cuda", "tpu", "meta"])
def test_a_device_that_is_not_there_is_one_line(dataset, tmp_path, capsys, device):
    if device == "cuda" and torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    assert train(dataset, tmp_path / "x.pt", "--epochs", "1", "--device", device) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"--device {device}" in err[0], err
    assert not (tmp_path / "x.pt").exists()


ON_A_GPU = [pytest.mark.gpu,
            pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU (run it on a lent one)")]


# the "cpu" case runs the same steps everywhere, so that the test itself is checked where no GPU is
@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=ON_A_GPU)])
@pytest.mark.parametrize("precision", ["fp32", "bf16"])
def test_training_on_a_gpu_writes_a_cpu_checkpoint_and_resumes(dataset, tmp_path, device, precision):
    """On a lent GPU: the same command with --device cuda trains, evaluates each epoch there, writes
    a checkpoint that loads on the CPU, and resumes from its state on the CPU."""
    out = tmp_path / "g.pt"
    held_out = ("--val-fraction", "0.3")  # the default 0.1 holds out none of the tiny dataset's scenes
    assert train(dataset, out, "--epochs", "1", "--device", device, "--precision", precision, *held_out) == 0
    metrics = json.loads((tmp_path / "g.json").read_text())
    assert (metrics["device"] != "cpu") == (device != "cpu")
    assert metrics["examples"]["val_full_horizon_scored"] > 0 and metrics["final"]["val_minADE"] > 0
    model = load_model(out)
    assert all(v.device.type == "cpu" for v in model.state_dict().values())
    assert train(dataset, out, "--epochs", "2", "--precision", precision, *held_out) == 0  # the CPU goes on
    assert [e["epoch"] for e in json.loads((tmp_path / "g.json").read_text())["epochs"]] == [1, 2]
    # evaluation draws the same noise on either device; only the float kernels differ
    res = {}
    for where in dict.fromkeys(("cpu", device)):  # the CPU once where it is the device
        path = tmp_path / f"eval_{where}.json"
        assert main(["-q", "eval", "rollout", "--data", str(dataset), "--split", "all", "--checkpoint", str(out),
                     "--device", where, "--json", str(path)]) == 0
        res[where] = json.loads(path.read_text())["methods"]["cvae_dsa"]
    assert res["cpu"]["minADE"] > 0
    if device != "cpu":
        assert res[device]["minADE"] == pytest.approx(res["cpu"]["minADE"], rel=1e-2)


def test_bf16_training_keeps_float32_weights_and_resumes_only_in_bf16(dataset, tmp_path):
    """bf16 runs the forward pass under autocast; the checkpoint is float32, its numbers finite and
    not those of the float32 run; a float32 command does not resume a bf16 state (nor the reverse)."""
    fp, bf = tmp_path / "fp.pt", tmp_path / "bf.pt"
    assert train(dataset, fp, "--epochs", "1") == 0
    assert train(dataset, bf, "--epochs", "1", "--precision", "bf16") == 0
    mf, mb = load_model(fp).state_dict(), load_model(bf).state_dict()
    assert all(v.dtype == mf[k].dtype for k, v in mb.items())
    assert all(torch.isfinite(v).all() for v in mb.values() if v.is_floating_point())
    assert any(not torch.equal(v, mf[k]) for k, v in mb.items() if v.is_floating_point())
    loss = json.loads((tmp_path / "bf.json").read_text())["final"]["train_loss"]
    assert loss == loss and abs(loss) < 1e6
    assert train(dataset, bf, "--epochs", "2") == 2  # fp32 asked, bf16 state: not the same run
    assert train(dataset, bf, "--epochs", "2", "--precision", "bf16") == 0


@pytest.mark.parametrize("native", [False, True, None])
def test_bf16_on_a_cpu_without_bf16_hardware_warns_once_and_trains(dataset, tmp_path, capsys, monkeypatch, native):
    """Emulated bfloat16 trains several times slower than float32: one warning line, then the run;
    a CPU that has it (or a torch that cannot tell) trains without one, and fp32 never warns."""
    monkeypatch.setattr(devices, "cpu_bf16_native", lambda: native)
    assert train(dataset, tmp_path / "bf.pt", "--epochs", "1", "--precision", "bf16") == 0
    err = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    if native is not False:
        assert err == []
        return
    assert len(err) == 1 and "--precision bf16" in err[0] and "--precision fp32" in err[0], err
    assert train(dataset, tmp_path / "fp.pt", "--epochs", "1") == 0  # the same CPU in float32: no warning
    assert "warning" not in capsys.readouterr().err
    cpu = json.loads((tmp_path / "fp.json").read_text())["cpu"]
    assert torch.backends.cpu.get_cpu_capability() in cpu and "no bf16 hardware" in cpu


def test_train_without_dsa_writes_that_config(dataset, tmp_path):
    out = tmp_path / "nodsa.pt"
    assert train(dataset, out, "--epochs", "1", "--no-dsa") == 0
    assert load_model(out).cfg.use_dsa is False


def test_best_of_fine_tunes_a_plain_checkpoint_and_is_stored(dataset, tmp_path, capsys):
    """--best-of K --init a plain checkpoint: allowed (it only weighs the loss), written into the new
    checkpoint; a negative K is one line."""
    base = tmp_path / "base.pt"
    assert train(dataset, base, "--epochs", "1") == 0
    best = tmp_path / "best.pt"
    assert train(dataset, best, "--epochs", "1", "--init", str(base), "--best-of", "3", "--best-of-weight", "0.5") == 0
    cfg = load_model(best).cfg
    assert (cfg.best_of, cfg.best_of_weight) == (3, 0.5) and load_model(base).cfg.best_of == 0
    capsys.readouterr()
    assert train(dataset, tmp_path / "bad.pt", "--epochs", "1", "--best-of", "-1") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "best_of" in err[0], err


def test_vocab_command(dataset, tmp_path):
    out = tmp_path / "vocab.npz"
    assert main(["-q", "train", "vocab", "--data", str(dataset), "-o", str(out), "--size", "24"]) == 0
    vocab = MotionVocab.load(out)
    assert 1 <= len(vocab) <= 24
    report = json.loads(out.with_suffix(".json").read_text())
    assert report["tokens"] == len(vocab) and report["coverage_max_error_m"] <= vocab.epsilon_m + 1e-9


def test_eval_rollout_reports_every_method(dataset, tmp_path):
    ck = tmp_path / "r.pt"
    assert train(dataset, ck, "--epochs", "1") == 0
    out = tmp_path / "eval.json"
    assert main(["-q", "eval", "rollout", "--data", str(dataset), "--split", "all", "--checkpoint", str(ck),
                 "--checkpoint-no-dsa", str(ck), "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert set(report["methods"]) == {"constant_velocity", "constant_lane", "cvae_no_dsa", "cvae_dsa"}
    for m in report["methods"].values():
        assert m["minADE"] <= m["avgADE"] + 1e-12 and m["minFDE"] <= m["avgFDE"] + 1e-12
        assert m["time_per_trajectory_s"] > 0
    assert report["methods"]["cvae_dsa"]["samples"] == 5
    # the CVAE's errors by the neighbours around at t_rev: the buckets partition the vehicles, and
    # their minFDE weighted by vehicles is the whole minFDE
    buckets = report["methods"]["cvae_dsa"]["by_neighbours"]
    n = sum(b["contexts"] for b in buckets)
    assert n == report["methods"]["cvae_dsa"]["num_contexts"]
    assert {b["neighbours"] for b in buckets} <= {"0", "1-3", "4-9", "10+"}
    assert sum(b["contexts"] * b["minFDE"] for b in buckets) / n == pytest.approx(
        report["methods"]["cvae_dsa"]["minFDE"])
    # and with or without a neighbour in the lane close ahead or behind: the two groups likewise
    groups = report["methods"]["cvae_dsa"]["by_lane_neighbour"]
    assert {g["lane_neighbour"] for g in groups} <= {"yes", "no"} and sum(g["contexts"] for g in groups) == n
    assert sum(g["contexts"] * g["minFDE"] for g in groups) / n == pytest.approx(
        report["methods"]["cvae_dsa"]["minFDE"])
    # synthetic agents follow their lanes at constant speed: the lane baseline beats straight lines
    cl, cv = report["methods"]["constant_lane"], report["methods"]["constant_velocity"]
    assert cl["minADE"] < cv["minADE"]
    last = tmp_path / "last.json"
    assert main(["-q", "eval", "rollout", "--data", str(dataset), "--split", "all", "--checkpoint", str(ck),
                 "--t-rev", "last", "--json", str(last)]) == 0
    assert json.loads(last.read_text())["num_examples"] < report["num_examples"]


def test_bad_checkpoint_is_one_line_and_exit_code_2(dataset, tmp_path, capsys):
    bad = tmp_path / "bad.pt"
    bad.write_text("garbage")
    code = main(["eval", "rollout", "--data", str(dataset), "--checkpoint", str(bad), "--json",
                 str(tmp_path / "e.json")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and str(bad) in err


def test_learning_rate_drop_resumes_a_finished_run(dataset, tmp_path):
    W = ("--warmup-steps", "0")  # 2 steps per tiny epoch: a warm-up would cover them all
    a, b, c = tmp_path / "a.pt", tmp_path / "b.pt", tmp_path / "c.pt"
    assert train(dataset, a, *W, "--epochs", "1") == 0
    # the finished constant-rate run goes on with a drop after its last epoch
    assert train(dataset, a, *W, "--epochs", "2", "--lr-drop-epoch", "2") == 0
    assert train(dataset, b, *W, "--epochs", "2", "--lr-drop-epoch", "2") == 0  # the same schedule uninterrupted
    assert train(dataset, c, *W, "--epochs", "2") == 0  # no drop
    ma, mb, mc = (load_model(p).state_dict() for p in (a, b, c))
    assert all(torch.equal(v, mb[k]) for k, v in ma.items())
    assert not all(torch.equal(v, mc[k]) for k, v in ma.items())  # the drop changed epoch 2
    # epoch 2 ran at 0.1 x lr: another factor (or no drop) for it is another run
    assert train(dataset, a, *W, "--epochs", "3", "--lr-drop-epoch", "2", "--lr-drop-factor", "0.5") == 2
    assert train(dataset, a, *W, "--epochs", "3") == 2
    assert train(dataset, a, *W, "--epochs", "3", "--lr-drop-epoch", "2") == 0
    assert train(dataset, a, *W, "--epochs", "3", "--lr-drop-factor", "2") == 2  # a "drop" must not raise the rate


def test_learning_rate_schedule():
    from coster_sumo.rollout.train import TrainConfig, learning_rate

    t = TrainConfig(lr=1e-3, warmup_steps=10, lr_drop_epoch=3, lr_drop_factor=0.1)
    assert learning_rate(0, t, 0) == pytest.approx(1e-4)  # warm-up
    assert learning_rate(50, t, 1) == pytest.approx(1e-3)
    assert learning_rate(80, t, 2) == pytest.approx(1e-4)  # epoch 3 (1-based) and on
    assert learning_rate(80, TrainConfig(lr=1e-3, warmup_steps=10), 2) == pytest.approx(1e-3)


def test_init_starts_from_a_checkpoint_s_weights_and_resumes_only_with_them(dataset, tmp_path):
    """``--init`` loads the weights (a zero learning rate leaves them as they were: without ``--init`` the
    seed's fresh weights come out); another model setting is one line naming the file; the run's state
    resumes only with the same starting checkpoint."""
    a, b, c, fresh = tmp_path / "a.pt", tmp_path / "b.pt", tmp_path / "c.pt", tmp_path / "fresh.pt"
    assert train(dataset, a, "--epochs", "1") == 0
    assert train(dataset, b, "--epochs", "1", "--seed", "3") == 0
    zero = ("--lr", "0", "--seed", "1")
    assert train(dataset, c, "--epochs", "1", "--init", str(a), *zero) == 0
    assert train(dataset, fresh, "--epochs", "1", *zero) == 0
    ma, mc, mf = (load_model(p).state_dict() for p in (a, c, fresh))
    assert all(torch.equal(v, mc[k]) for k, v in ma.items())
    assert not all(torch.equal(v, mf[k]) for k, v in ma.items())
    metrics = json.loads((tmp_path / "c.json").read_text())
    assert metrics["init"] == str(a.resolve()) and len(metrics["train_config"]["init"]) == 64
    # the state of c started from a: resuming it from b, or from fresh weights, is another run
    assert train(dataset, c, "--epochs", "2", "--init", str(b), *zero) == 2
    assert train(dataset, c, "--epochs", "2", *zero) == 2
    assert train(dataset, c, "--epochs", "2", "--init", str(a), *zero) == 0


def test_init_from_another_model_setting_is_one_line(dataset, tmp_path, capsys):
    a = tmp_path / "a.pt"
    assert train(dataset, a, "--epochs", "1") == 0
    capsys.readouterr()
    code = main(["train", "rollout", "--data", str(dataset), "-o", str(tmp_path / "b.pt"), *TINY, "--epochs", "1",
                 "--no-dsa", "--init", str(a)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and str(a) in err and "use_dsa" in err


def test_errors_by_neighbours_bucket_the_contexts():
    import numpy as np

    from coster_sumo.rollout.evaluate import by_neighbours

    truth = np.zeros((4, 3, 2))
    pred = np.zeros((4, 2, 3, 2))
    pred[:, :, :, 0] = np.array([1.0, 2.0, 3.0, 4.0])[:, None, None]  # context i is off by i + 1 m
    from coster_sumo.metrics import ade_fde

    out = by_neighbours(*ade_fde(pred, truth, np.ones((4, 3), bool)), np.array([0, 2, 12, 3]))
    assert [(b.group, b.label, b.contexts) for b in out] == [("neighbours", "0", 1), ("neighbours", "1-3", 2),
                                                              ("neighbours", "10+", 1)]
    assert [b.min_fde for b in out] == [1.0, 3.0, 3.0]


def test_lane_neighbour_is_an_agent_close_ahead_or_behind_in_the_same_direction():
    import numpy as np

    from coster_sumo.rollout.config import RolloutConfig
    from coster_sumo.rollout.evaluate import by_lane_neighbour, has_lane_neighbour

    scale = RolloutConfig().pos_scale_m
    # (along, aside [m], cos of the relative heading) of one neighbour at t_rev, one context each
    cases = [((12.0, 0.5, 1.0), True), ((-25.0, -1.0, 0.95), True), ((35.0, 0.0, 1.0), False),
             ((10.0, 3.0, 1.0), False), ((10.0, 0.0, -1.0), False), ((10.0, 0.0, 0.5), False)]
    nbr = np.zeros((len(cases) + 1, 11, 4, 12), np.float32)
    mask = np.zeros(nbr.shape[:3], bool)
    for i, ((along, aside, cos), _) in enumerate(cases):
        nbr[i, 0, 2, :5] = along / scale, aside / scale, 0.0, 0.0, cos
        mask[i, 0, 2] = True
    nbr[-1, 0, 1, :5] = 5.0 / scale, 0.0, 0.0, 0.0, 1.0  # in the lane, but masked out: padding
    nbr[0, 1, 0, :5] = 5.0 / scale, 0.0, 0.0, 0.0, 1.0  # a later step does not count
    mask[0, 1, 0] = True
    assert has_lane_neighbour(nbr, mask, scale).tolist() == [want for _, want in cases] + [False]
    ade = np.array([[1.0, 2.0], [3.0, 1.0], [5.0, 5.0]])
    out = by_lane_neighbour(ade, ade, np.array([True, True, False]))
    assert [(g.group, g.label, g.contexts, g.min_fde) for g in out] == [("lane_neighbour", "yes", 2, 1.0),
                                                                        ("lane_neighbour", "no", 1, 5.0)]
    assert [g.label for g in by_lane_neighbour(ade, ade, np.zeros(3, bool))] == ["no"]


def test_init_may_widen_the_attention_radius_and_nothing_that_sizes_a_weight(dataset, tmp_path, capsys):
    """--init fine-tunes with another --neighbor-radius (a mask, no weights); the radius is
    written into the new checkpoint, cannot pass the 80 m within which neighbours are kept, and
    a setting that sizes weights still refuses the start on one line."""
    base = tmp_path / "base.pt"
    assert train(dataset, base, "--epochs", "1") == 0
    wide = tmp_path / "wide.pt"
    assert train(dataset, wide, "--epochs", "1", "--init", str(base), "--neighbor-radius", "70") == 0
    assert load_model(wide).cfg.neighbor_radius_m == 70.0 and load_model(base).cfg.neighbor_radius_m == 50.0
    capsys.readouterr()
    assert train(dataset, tmp_path / "far.pt", "--epochs", "1", "--neighbor-radius", "90") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "90 m" in err[0] and "80 m" in err[0], err
    assert train(dataset, tmp_path / "w.pt", "--epochs", "1", "--init", str(base), "--latent", "8") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "latent" in err[0] and "neighbor_radius_m" not in err[0], err
