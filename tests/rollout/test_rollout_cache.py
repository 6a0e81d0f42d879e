"""The rollout feature cache: reused, rebuilt when scenes or encoding settings change, the same
numbers (and training results) as inputs built per batch; the prefetching helper."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from coster_sumo.cli.command_line import main
from coster_sumo.data import synthetic
from coster_sumo.errors import InputError
from coster_sumo.formats.scene_file import load_scene, save_scene
from coster_sumo.infra.prefetch import prefetch
from coster_sumo.rollout import cache as C
from coster_sumo.rollout.checkpoint import load_model
from coster_sumo.rollout.config import RolloutConfig
from coster_sumo.rollout.data import build_examples, to_tensors
from coster_sumo.rollout.model import RolloutCVAE, trim_padding
from coster_sumo.rollout.train import TrainConfig, learning_rate, split_scene_files

CFG = RolloutConfig(hidden=32, heads=4, latent=4)


@pytest.fixture()
def dataset(tmp_path):
    root = tmp_path / "data"
    (root / "scenes").mkdir(parents=True)
    for name in ("two_lane_road", "four_way_junction", "merge"):
        save_scene(synthetic.ALL[name](), root / "scenes" / f"{name}.npz")
    return root


def scene_files(root):
    return sorted((root / "scenes").glob("*.npz"))


def test_cache_is_built_once_then_reused(dataset, monkeypatch):
    paths = scene_files(dataset)
    first = C.cached_examples(paths, CFG, 2, workers=1)
    assert first.folder.parent == dataset / C.CACHE_DIR_NAME and (first.folder / "meta.json").is_file()
    assert json.loads((first.folder / "meta.json").read_text())["examples"] == len(first) > 0

    def no_build(*args, **kwargs):
        raise AssertionError("the cache was rebuilt")

    monkeypatch.setattr(C, "build_feature_cache", no_build)
    again = C.cached_examples(paths, CFG, 2)
    assert again.folder == first.folder and len(again) == len(first)
    # the model's width is no input encoding setting: same features
    assert C.cached_examples(paths, RolloutConfig(hidden=64, heads=4), 2).folder == first.folder
    assert isinstance(again.arrays["map_vec"], np.memmap)


def test_no_scene_files_is_an_error_not_an_empty_cache(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(InputError):
        C.cached_examples([], CFG, 2)
    assert not any(tmp_path.iterdir())


def test_cache_is_rebuilt_when_a_scene_or_a_setting_changes(dataset):
    paths = scene_files(dataset)
    base = C.cached_examples(paths, CFG, 2, workers=1).folder
    other_cfg = C.cached_examples(paths, RolloutConfig(hidden=32, heads=4, latent=4, map_radius_m=40.0), 2,
                                  workers=1)
    assert other_cfg.folder != base
    assert C.cached_examples(paths, CFG, 3, workers=1).folder != base  # min_steps
    assert C.cached_examples(paths[:2], CFG, 2, workers=1).folder != base  # another set of scenes
    scene = load_scene(paths[0])
    scene.tracks.x[:] += 1.0  # the same file name, other content
    save_scene(scene, paths[0])
    moved = C.cached_examples(paths, CFG, 2, workers=1)
    assert moved.folder != base
    assert not np.array_equal(moved.arrays["origin"], C.CachedExamples(base).arrays["origin"])


def test_cached_batches_equal_batches_built_from_the_scenes(dataset):
    paths = scene_files(dataset)
    fresh = build_examples([load_scene(p) for p in paths], CFG)
    cached = C.cached_examples(paths, CFG, 2, workers=2)  # worker processes write the same arrays
    np.testing.assert_array_equal(fresh.index, cached.index)
    rows = np.random.default_rng(0).permutation(len(fresh))[:48]
    for horizon in (None, CFG.max_horizon):
        a = trim_padding(to_tensors(fresh.batch(rows, CFG, horizon=horizon)))
        b = trim_padding(to_tensors(cached.batch(rows, CFG, horizon=horizon)))
        assert a.keys() == b.keys()
        for k in a:
            assert a[k].shape == b[k].shape and torch.equal(a[k], b[k]), k
    # one training step on either gives the same loss and the same weights
    torch.set_num_threads(1)
    results = []
    for examples in (fresh, cached):
        torch.manual_seed(0)
        model = RolloutCVAE(CFG)
        opt = torch.optim.AdamW(model.parameters(), lr=1e-3)
        t = to_tensors(examples.batch(rows, CFG))
        traj, mask = t.pop("traj"), t.pop("step_mask")
        t.pop("origin")
        out = model(t, traj, mask)
        assert out.loss is not None
        out.loss.backward()
        opt.step()
        results.append((float(out.loss.detach()), model.state_dict()))
    assert results[0][0] == results[1][0]
    for k, v in results[0][1].items():
        assert torch.equal(v, results[1][1][k]), k


TINY = ["--hidden", "16", "--heads", "2", "--latent", "4", "--batch-size", "32", "--examples-per-epoch", "64",
        "--max-val-examples", "16", "--threads", "1"]


def test_training_on_the_cache_equals_training_without_it_and_resumes(dataset, tmp_path):
    a, b, c = tmp_path / "a.pt", tmp_path / "b.pt", tmp_path / "c.pt"
    cache_dir = tmp_path / "features"
    common = ["-q", "train", "rollout", "--data", str(dataset), *TINY]
    assert main([*common, "-o", str(a), "--epochs", "2", "--cache-dir", str(cache_dir)]) == 0
    _, held_out = split_scene_files(dataset, 0.1, 0)
    assert len(list(cache_dir.glob("rollout-*"))) == 1 + bool(held_out)  # training (and held-out) scenes
    assert not (dataset / C.CACHE_DIR_NAME).exists()
    assert main([*common, "-o", str(b), "--epochs", "2", "--no-cache"]) == 0
    assert main([*common, "-o", str(c), "--epochs", "1", "--cache-dir", str(cache_dir)]) == 0
    assert main([*common, "-o", str(c), "--epochs", "2", "--cache-dir", str(cache_dir)]) == 0  # resumed
    ma, mb, mc = (load_model(p).state_dict() for p in (a, b, c))
    for k, v in ma.items():
        assert torch.equal(v, mb[k]) and torch.equal(v, mc[k]), k
    history = {p: json.loads(p.with_suffix(".json").read_text())["epochs"] for p in (a, b, c)}
    assert [e["epoch"] for e in history[c]] == [1, 2]
    losses = {p: [e["train_loss"] for e in h] for p, h in history.items()}
    assert losses[a] == losses[b] == losses[c]


def test_learning_rate_warms_up_linearly():
    t = TrainConfig(lr=1e-3, warmup_steps=4)
    assert [learning_rate(s, t) for s in range(6)] == pytest.approx([2.5e-4, 5e-4, 7.5e-4, 1e-3, 1e-3, 1e-3])
    assert learning_rate(0, TrainConfig(lr=5e-4, warmup_steps=0)) == 5e-4


def test_prefetch_keeps_order_and_hands_on_errors():
    assert list(prefetch(lambda x: x * x, range(7), depth=2)) == [x * x for x in range(7)]

    def boom(x: int) -> int:
        if x == 3:
            raise ValueError("bad item")
        return x

    got = []
    with pytest.raises(ValueError, match="bad item"):
        for v in prefetch(boom, range(6)):
            got.append(v)
    assert got == [0, 1, 2]
    it = prefetch(lambda x: x, range(1000), depth=1)
    assert next(it) == 0
    it.close()  # leaving early stops the producer


def test_padding_contents_do_not_reach_the_model():
    """What padded map chunks and neighbour slots hold changes neither the loss nor the samples."""
    ex = build_examples([synthetic.four_way_junction()], CFG)
    t = to_tensors(ex.batch(np.arange(0, len(ex), max(1, len(ex) // 16)), CFG))
    traj, mask = t.pop("traj"), t.pop("step_mask")
    t.pop("origin")
    noisy = dict(t)
    gen = torch.Generator().manual_seed(5)
    for k, m in (("nbr", t["nbr_mask"]), ("map_vec", t["map_mask"][..., None]), ("map_attr", t["map_mask"]),
                 ("map_pos", t["map_mask"])):
        noise = torch.randn(t[k].shape, generator=gen)
        noisy[k] = torch.where(m[..., None], t[k], noise)
    torch.set_num_threads(1)
    torch.manual_seed(0)
    model = RolloutCVAE(CFG)
    losses = []
    for inputs in (t, noisy):
        torch.manual_seed(1)
        out = model(inputs, traj, mask)
        assert out.loss is not None
        losses.append(float(out.loss.detach()))
        samples = model.sample(inputs, 3, generator=torch.Generator().manual_seed(2))
        losses.append(float(samples.sum()))
    assert losses[:2] == losses[2:]


@pytest.mark.skipif(not Path("/proc/self/smaps").is_file(), reason="needs Linux /proc/self/smaps")
def test_mapped_arrays_are_advised_random_access_without_read_ahead(dataset):
    """A batch touches a few kB at random places: with the kernel's read-ahead a cache larger than
    memory was read hundreds of times over (bench/bench_cache_io.py). The kernel shows the advice
    as the ``rr`` flag of the mapping."""
    ex = C.cached_examples(scene_files(dataset), CFG, 2, workers=1)
    flags: dict[str, set[str]] = {}
    current = None
    for line in Path("/proc/self/smaps").read_text().splitlines():
        parts = line.split()
        if len(parts) >= 6 and "-" in parts[0] and str(ex.folder) in line:
            current = Path(parts[-1]).stem
        elif line.startswith("VmFlags:") and current is not None:
            flags[current] = set(parts[1:])
            current = None
        elif len(parts) >= 5 and "-" in parts[0]:
            current = None
    assert {"traj", "map_vec", "nbr"} <= set(flags)
    assert all("rr" in flags[name] for name in ("traj", "map_vec", "nbr", "state", "nbr_mask"))
    assert ex.batch(np.arange(min(3, len(ex))), CFG)["traj"].shape[0] == min(3, len(ex))


def test_scenes_packed_for_a_gpu_machine_give_the_same_examples(dataset, tmp_path, monkeypatch):
    """bench/pack_for_device.py writes the clips at 2 Hz, the steps the training keeps: the
    examples built from the packed copies are those of the full clips, number and features."""
    import runpy
    import sys

    out = tmp_path / "pack"
    monkeypatch.setattr(sys, "argv", ["pack_for_device.py", str(dataset), "--out", str(out), "--no-wheels",
                                      "--max-mb", "50"])
    runpy.run_path(str(Path(__file__).resolve().parents[2] / "bench" / "pack_for_device.py"), run_name="__main__")
    packed = scene_files(out)
    assert [p.name for p in packed] == [p.name for p in scene_files(dataset)]
    assert json.loads((out / "pack.json").read_text())["scenes"] == 3
    assert all(load_scene(p).num_steps == 19 for p in packed)  # 91 steps at 10 Hz -> 19 at 2 Hz
    full = build_examples([load_scene(p) for p in scene_files(dataset)], CFG)
    small = build_examples([load_scene(p) for p in packed], CFG)
    assert len(small) == len(full) > 0
    rows = np.arange(len(full))
    a, b = full.batch(rows, CFG), small.batch(rows, CFG)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
