"""One language on the command line (issue 42): every subcommand's --help walked and checked for
the shared flags and wording, the same defaults in run, regress and the API, and one wording for
a missing input whatever the command."""

from __future__ import annotations

import argparse
import inspect
import re
import sys
from pathlib import Path

import pytest

from coster_sumo.cli.command_line import _subcommands, build_parser, main
from coster_sumo.core.spec import GenerationConfig

REPO = Path(__file__).resolve().parents[2]
MARKUP = re.compile(r"``|:(func|mod|class|data|meth|attr):`")


def _commands() -> list[tuple[str, argparse.ArgumentParser]]:
    return [(p.prog.removeprefix("coster-sumo "), p) for p in _subcommands(build_parser())
            if not any(isinstance(a, argparse._SubParsersAction) for a in p._actions)]


COMMANDS = _commands()


def test_every_command_is_walked():
    names = {n for n, _ in COMMANDS}
    assert {"run", "demo", "regress", "replay", "export", "convert", "simulate", "snapshot", "corpus build",
            "corpus card", "eval curves", "eval prior", "eval rollout", "eval scenarios", "train prior",
            "train rollout", "train vocab"} <= names


@pytest.mark.parametrize(("name", "parser"), COMMANDS, ids=[n for n, _ in COMMANDS])
def test_help_speaks_one_language(name, parser):
    text = parser.format_help()
    assert not MARKUP.search(text), f"{name}: reST markup in --help"
    options = {o: a for a in parser._actions for o in a.option_strings}
    assert "--quiet" in options and "-q" in options and "--debug" in options
    # whatever the command writes is named by -o/--out; the old spellings parse but are not shown
    writes = [a for a in parser._actions if a.dest in ("out", "output", "json")]
    for a in writes:
        assert a.dest == "out" and {"-o", "--out"} <= set(a.option_strings), f"{name}: {a.option_strings}"
    assert "--output" not in text and "--json" not in text, f"{name}: an old spelling shown in --help"
    for a in parser._actions:  # positionals in capitals, like the README's command table
        if not a.option_strings and a.dest != "help":
            shown = a.metavar or a.dest
            assert isinstance(shown, str) and shown.isupper(), f"{name}: positional shown as {shown!r}"


@pytest.mark.parametrize(("argv", "alias"), [
    (["simulate", "X.sumocfg", "--output", "D"], "--output"),
    (["eval", "curves", "m.json", "--output", "c.png"], "--output"),
    (["eval", "prior", "--data", "D", "--json", "p.json"], "--json"),
    (["eval", "rollout", "--data", "D", "--json", "r.json"], "--json"),
])
def test_old_spellings_still_parse(argv, alias):
    args = build_parser().parse_args(argv)
    assert str(args.out) == argv[argv.index(alias) + 1]


def test_corpus_build_help_is_about_build():
    build = dict(COMMANDS)["corpus build"].format_help()
    card = dict(COMMANDS)["corpus card"].format_help()
    assert "writes DATASET/card.md" not in build and "card.md" in card


def test_version(capsys):
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0 and re.fullmatch(r"coster-sumo \S+\n", capsys.readouterr().out)


def test_defaults_agree_across_run_regress_and_the_api():
    from coster_sumo.api import plan_adversaries

    commands = dict(COMMANDS)
    # the API's settings are a GenerationConfig's, its defaults where none is given
    assert inspect.signature(plan_adversaries).parameters["generation"].default is None
    for key in ("variants", "samples"):
        run = commands["run"].get_default(key)
        assert run == commands["regress"].get_default(key) == getattr(GenerationConfig(), key)
    assert {"--begin", "--end", "--duration", "--seed", "--target"} <= {
        o for a in commands["regress"]._actions for o in a.option_strings}


def _missing(tmp_path: Path) -> list[tuple[list[str], Path, str]]:
    f = tmp_path / "missing.sumocfg"
    return [(["run", str(f)], f, "file"), (["replay", str(f)], f, "file"), (["snapshot", str(f)], f, "file"),
            (["regress", str(f), "--planner", "sumo"], f, "file or folder"),
            (["simulate", str(f), "-o", str(tmp_path / "d")], f, "file"),
            (["convert", str(tmp_path / "missing.tfrecord"), "-o", str(tmp_path / "c")],
             tmp_path / "missing.tfrecord", "file"),
            (["export", str(tmp_path / "missing_run")], tmp_path / "missing_run", "folder"),
            (["eval", "curves", str(tmp_path / "m.json"), "-o", str(tmp_path / "c.png")], tmp_path / "m.json", "file")]


def test_a_missing_input_has_one_wording_in_every_command(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for argv, path, kind in _missing(tmp_path):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [f"coster-sumo: error: {path}: no such {kind}"], (argv, err)
    assert sorted(p.name for p in tmp_path.iterdir()) == [], "a command wrote something for a missing input"


def test_export_defaults_to_what_is_installed(monkeypatch):
    from coster_sumo.exports import openscenario, run_folder

    assert dict(COMMANDS)["export"].get_default("format") is None
    monkeypatch.setattr(openscenario, "require_extra", lambda: None)
    assert run_folder.available_formats() == "all"

    def missing() -> None:
        raise openscenario.InputError("the extra is missing")

    monkeypatch.setattr(openscenario, "require_extra", missing)
    assert run_folder.available_formats() == "sumo"


def test_replay_writes_to_out_not_beside_its_input():
    assert dict(COMMANDS)["replay"].get_default("out") == Path("out/replay")


PLANNER = '''
class Mine:
    name = "mine"

    def additional_files(self, workdir):
        return []

    def setup(self, session, target_id):
        pass

    def before_step(self, session, target_id, t_next, present):
        pass
'''


def test_planners_from_the_working_directory_and_from_a_file(tmp_path, monkeypatch):
    from coster_sumo.sim.planners import make_planner

    (tmp_path / "my_planner_42.py").write_text(PLANNER)
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "other.py").write_text(PLANNER)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "path", [p for p in sys.path if p not in ("", ".", str(tmp_path))])
    assert type(make_planner("my_planner_42:Mine")).__name__ == "Mine"
    assert type(make_planner("sub/other.py:Mine")).__name__ == "Mine"
    with pytest.raises(Exception, match=r"sub/none.py: no such file"):
        make_planner("sub/none.py:Mine")
