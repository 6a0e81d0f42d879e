"""``coster-sumo eval curves``: the model cards' learning-curve pictures."""

from __future__ import annotations

import json

import pytest

from coster_sumo.cli.command_line import main


def test_curves_of_a_rollout_and_a_prior_run(tmp_path, capsys):
    rollout = tmp_path / "rollout.json"
    rollout.write_text(json.dumps({"epochs": [{"train_loss": 9.0 - e, "val_loss": 8.0 - e, "val_minADE": 2.0 - 0.1 * e,
                                               "val_minFDE": 5.0 - 0.3 * e} for e in range(4)]}))
    prior = tmp_path / "prior.json"
    prior.write_text(json.dumps({"history": [{"epoch": e + 1, "train_loss": 1.0 / (e + 1), "val_loss": 1.1 / (e + 1)}
                                             for e in range(3)]}))
    out = tmp_path / "curves.png"
    assert main(["eval", "curves", f"dsa={rollout}", str(prior), "-o", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    printed = capsys.readouterr().out
    assert "dsa (4 epochs)" in printed and "prior (3 epochs)" in printed


def test_a_file_without_epochs_is_one_line(tmp_path, capsys):
    bad = tmp_path / "m.json"
    bad.write_text(json.dumps({"final": {}}))
    assert main(["eval", "curves", str(bad), "-o", str(tmp_path / "c.png")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "m.json" in err[0] and "per-epoch" in err[0]
    assert not (tmp_path / "c.png").exists()


def test_the_priors_nested_held_out_loss_is_read():
    """`train prior` writes its held-out numbers as {"val": {"loss": ...}}; the curve must show them."""
    from coster_sumo.pipeline.viz import training_history

    rows = training_history({"history": [{"epoch": 1, "train_loss": 0.79, "val": {"loss": 0.69, "speed_ce": 3.1}}]})
    assert rows[0]["val_loss"] == 0.69 and rows[0]["train_loss"] == 0.79 and rows[0]["val_speed_ce"] == 3.1


@pytest.fixture()
def marks_drawn(monkeypatch):
    """The marks ``eval curves`` hands to the picture (it is still drawn)."""
    from coster_sumo.pipeline import viz

    seen: dict = {}
    real = viz.training_curves

    def spy(runs, path, marks=None):
        seen["marks"] = marks
        return real(runs, path, marks)

    monkeypatch.setattr(viz, "training_curves", spy)
    return seen


def test_a_learning_rate_drop_is_marked(tmp_path, marks_drawn):
    run = tmp_path / "rollout.json"
    run.write_text(json.dumps({"train_config": {"lr_drop_epoch": 3, "lr_drop_factor": 0.1},
                               "epochs": [{"train_loss": 5.0 - e, "val_loss": 5.0 - e} for e in range(4)]}))
    plain = tmp_path / "plain.json"
    plain.write_text(json.dumps({"train_config": {"lr_drop_epoch": 0}, "epochs": [{"train_loss": 1.0}]}))
    out = tmp_path / "c.png"
    assert main(["eval", "curves", str(run), str(plain), "-o", str(out)]) == 0
    assert marks_drawn["marks"] == {3: "lr x 0.1"}
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_file_s_own_marks_are_drawn_and_a_bad_one_is_one_line(tmp_path, marks_drawn, capsys):
    """Joined histories of a run continued with --init carry their rate changes as "marks"."""
    run = tmp_path / "joined.json"
    run.write_text(json.dumps({"marks": [[3, "lr x 0.1"], [5, "lr x 0.01"]],
                               "epochs": [{"train_loss": 6.0 - e, "val_loss": 6.0 - e} for e in range(6)]}))
    assert main(["eval", "curves", str(run), "-o", str(tmp_path / "c.png")]) == 0
    assert marks_drawn["marks"] == {3: "lr x 0.1", 5: "lr x 0.01"}
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"marks": [["x"]], "epochs": [{"train_loss": 1.0}]}))
    capsys.readouterr()
    assert main(["eval", "curves", str(bad), "-o", str(tmp_path / "d.png")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.json" in err[0] and "mark" in err[0]
