"""Nothing lost, nothing counted twice, nothing left running: output folders and faults.

One test per finding of the fault review (numbered as there): each failed on the code before
coster_sumo.infra.outdir existed and passes now. The slow harness that kills commands at chosen moments
is tests/contract/test_faults.py.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from coster_sumo.batch.executor import is_transient
from coster_sumo.batch.sources import parse_sources, scene_key
from coster_sumo.cli.command_line import main
from coster_sumo.core.spec import ScenarioSpec
from coster_sumo.errors import InputError
from coster_sumo.infra.outdir import (
    MARKER,
    OutputLock,
    check_output,
    clean_leftovers,
    clean_leftovers_in,
    new_staging,
    publish,
    read_marker,
)

REPO = Path(__file__).resolve().parents[2]
NET = REPO / "networks" / "intersection"
CFG = NET / "intersection.sumocfg"
FAST = ["--init", "random", "--rollout", "cv", "--end", "45", "--variants", "2", "--samples", "50"]


def _run(out: Path, *extra: str) -> int:
    return main(["-q", "run", str(CFG), *FAST, "-o", str(out), *extra])


def _tree(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


# ---------------------------------------------------------------- 1. run/demo never destroy a folder

def test_run_refuses_a_folder_holding_a_users_file(tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    assert _run(out) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "did not write" in err[0] and str(out) in err[0]
    assert (out / "notes.txt").read_text() == "mine"


def test_run_refuses_the_working_directory_and_its_parents(tmp_path, capsys, monkeypatch):
    work = tmp_path / "work"
    (work / "sub").mkdir(parents=True)
    (work / "important.txt").write_text("x")
    (work / "sub" / "thesis.tex").write_text("y")
    before = _tree(work)
    monkeypatch.chdir(work / "sub")
    for out in (".", "..", str(work)):
        assert _run(Path(out)) == 2, out
        assert "working directory" in capsys.readouterr().err
    assert _tree(work) == before


def test_run_refuses_a_folder_holding_its_inputs(tmp_path, capsys):
    net = tmp_path / "net"
    shutil.copytree(NET, net)
    before = _tree(net)
    for out in (net, tmp_path):
        assert main(["-q", "run", str(net / "intersection.sumocfg"), *FAST, "-o", str(out)]) == 2
        assert "holds the input" in capsys.readouterr().err
    assert _tree(net) == before


def test_an_earlier_output_is_replaced_only_with_overwrite_and_only_whole(tmp_path, capsys):
    out = tmp_path / "o"
    assert _run(out) == 0
    marker = read_marker(out)
    assert marker is not None and marker["kind"] == "run" and "summary.json" in marker["files"]
    first = _tree(out)
    assert _run(out) == 2 and "--overwrite" in capsys.readouterr().err
    assert _tree(out) == first
    (out / "variants" / "0" / "my_notes.txt").write_text("mine")  # a user's file inside it
    assert _run(out, "--overwrite") == 2 and "my_notes.txt" in capsys.readouterr().err
    (out / "variants" / "0" / "my_notes.txt").unlink()
    assert _run(out, "--overwrite", "--seed", "1") == 0
    assert json.loads((out / "summary.json").read_text())["seed"] == 1
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]  # no staging, no lock left


def test_an_existing_file_as_out_fails_before_any_work(tmp_path, capsys):
    out = tmp_path / "file"
    out.write_text("x")
    assert _run(out) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a folder" in err[0] and out.read_text() == "x"


def test_a_kill_between_the_two_renames_loses_nothing(tmp_path, monkeypatch):
    out = tmp_path / "o"
    old = new_staging(out)
    (old / "summary.json").write_text("old")
    publish(old, out, kind="run")
    new = new_staging(out)
    (new / "summary.json").write_text("new")
    real_replace = os.replace
    calls = []

    def killed_after_first(src, dst):  # the old output moved aside, then the process "dies"
        calls.append((src, dst))
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", killed_after_first)
    with pytest.raises(KeyboardInterrupt):
        publish(new, out, kind="run")
    monkeypatch.setattr(os, "replace", real_replace)
    assert not out.exists() and new.exists()  # the state a SIGKILL at that moment leaves
    with OutputLock(out):  # what the next command on this output does first
        done = clean_leftovers(out)
    assert (out / "summary.json").read_text() == "old"
    assert any("restored" in line for line in done) and not new.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o"]


def test_two_commands_on_one_output_the_second_refuses_in_one_line(tmp_path):
    out = tmp_path / "o"
    with OutputLock(out), pytest.raises(InputError, match="another coster-sumo command is writing it"):
        with OutputLock(out):
            pass
    with OutputLock(out):  # released: free again
        pass
    assert not (tmp_path / ".o.lock").exists()


def test_output_folders_get_the_users_umask(tmp_path):
    old = os.umask(0o022)
    try:
        staging = new_staging(tmp_path / "o")
    finally:
        os.umask(old)
    assert staging.stat().st_mode & 0o777 == 0o755


# ---------------------------------------------------------------- 2. hidden and staging folders are no scenes

def test_staging_folders_of_a_stopped_convert_are_no_scenes(tmp_path):
    scenes = tmp_path / "scenes"
    shutil.copytree(NET, scenes / "a")
    shutil.copytree(NET, scenes / f".b.staging.{os.getpid()}.0a0b")  # what a convert killed before its rename leaves
    shutil.copytree(NET, scenes / ".git" / "x")
    specs = parse_sources([str(scenes)])
    assert [s.config.parent.name for s in specs] == ["a"]
    assert clean_leftovers_in(scenes) and not (scenes / f".b.staging.{os.getpid()}.0a0b").exists()


# ---------------------------------------------------------------- 3. one resume key for the same work

def test_resume_key_names_the_weights_by_content_not_by_path(tmp_path, monkeypatch):
    models = tmp_path / "m"
    shutil.copytree(REPO / "models", models, ignore=shutil.ignore_patterns("*.md", "*.png", "*.json"))
    spec = ScenarioSpec(CFG, seed=0)
    monkeypatch.chdir(tmp_path)
    k1 = scene_key(spec, {"variants": 3, "models_dir": "m"})
    (tmp_path / "sub").mkdir()
    monkeypatch.chdir(tmp_path / "sub")
    assert scene_key(spec, {"variants": 3, "models_dir": "../m"}) == k1
    assert scene_key(spec, {"variants": 3, "models_dir": str(models)}) == k1
    (models / "vocab.npz").write_bytes((models / "vocab.npz").read_bytes() + b"\0")  # other weights
    assert scene_key(spec, {"variants": 3, "models_dir": str(models)}) != k1


# ---------------------------------------------------------------- 7. transient failures are retried

@pytest.mark.parametrize(("reason", "transient"), [
    ("timed out after 30 s (killed)", True),
    ("crashed (SIGKILL)", True),  # the kernel's OOM killer
    ("OSError: [Errno 28] No space left on device: 'x.npz'", True),
    ("MemoryError", True),
    ("crashed (SIGSEGV)", False),  # a SUMO crash on this input: it would crash again
    ("InputError: x.sumocfg: no such SUMO configuration", False),
])
def test_failures_of_the_machine_are_transient_those_of_the_input_are_not(reason, transient):
    assert is_transient(reason) is transient


# ---------------------------------------------------------------- 8. one line for a multi-target export

def test_check_output_names_a_foreign_kind(tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    (out / MARKER).write_text(json.dumps({"tool": "coster-sumo", "kind": "convert", "files": []}))
    (out / "summary.json").write_text("{}")
    with pytest.raises(InputError, match="output of coster-sumo convert, not of run"):
        check_output(out, kind="run", overwrite=True)


# ---------------------------------------------------------------- 4./5. hangs and crashes cost one variant

@pytest.mark.parametrize(("planner", "extra", "why"), [
    ("tests.misbehaving_planners:AbortOnce", (), "crashed (SIGABRT)"),
    ("tests.misbehaving_planners:HangOnce", ("--timeout", "20"), "timed out after 20 s"),
])
def test_a_crashing_or_hanging_variant_is_one_line_and_the_others_are_kept(tmp_path, capfd, monkeypatch,
                                                                           planner, extra, why):
    monkeypatch.setenv("COSTER_TEST_ONCE", str(tmp_path / "once"))
    out = tmp_path / "o"
    # the CVAE makes several variants (the constant-velocity baseline only one)
    assert _run(out, "--planner", planner, "--rollout", "cvae", "--samples", "200", "--variants", "3", *extra) == 1
    err = [ln for ln in capfd.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and why in err[0] and str(CFG) in err[0] and "adversary" in err[0], err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["num_variants"] == 2
    assert [f["reason"] for f in summary["generation"]["failed"]] == [f"its SUMO pass {why}" + (
        " (stopped)" if "timed out" in why else "")]


# ---------------------------------------------------------------- 6. nothing from outside the configuration's folder

def test_a_file_from_outside_the_configuration_is_named_not_copied(tmp_path):
    net = tmp_path / "net"
    shutil.copytree(NET, net)
    secret = tmp_path / "elsewhere" / "token.add.xml"
    secret.parent.mkdir()
    secret.write_text('<additional><!-- secret-token-42 --></additional>\n')
    cfg = net / "intersection.sumocfg"
    text = cfg.read_text()
    assert "<additional-files" not in text
    cfg.write_text(text.replace("</input>", f'    <additional-files value="{secret}"/>\n    </input>'))
    out = tmp_path / "o"
    assert main(["-q", "run", str(cfg), *FAST, "-o", str(out)]) == 0
    for variant in (out / "variants").iterdir():
        export = variant / "export"
        assert not any("secret-token-42" in p.read_text(errors="replace") for p in export.iterdir() if p.is_file()
                       and p.name != "variant.json")
        info = json.loads((export / "variant.json").read_text())["export"]
        assert info["outside_files"] == [str(secret)]
    assert main(["-q", "run", str(cfg), *FAST, "-o", str(tmp_path / "o2"), "--copy-outside"]) == 0
    assert (tmp_path / "o2" / "variants" / "0" / "export" / "token.add.xml").is_file()


# ---------------------------------------------------------------- 8. export of a run with several targets

def test_export_of_a_run_with_several_targets(tmp_path, capsys):
    out = tmp_path / "o"
    rc = _run(out, "--seed", "2", "--no-render", "--planner", "replay", "--target", "ego", "--target", "pre_W.1")
    assert rc == 0, capsys.readouterr().err
    capsys.readouterr()
    assert main(["export", str(out), "--format", "sumo"]) == 0
    printed = capsys.readouterr().out
    assert "target ego, variant 0: sumo -c" in printed
    marker = read_marker(out)
    assert marker is not None  # export's files are listed: a later --overwrite may replace them
    assert _run(out, "--overwrite") == 0


def test_a_net_truncated_by_a_full_disk_blames_the_disk(tmp_path, monkeypatch):
    from coster_sumo.converters.netconvert import _parse_xml

    net = tmp_path / "x.net.xml"
    net.write_text("<net><edge id='a'")  # what netconvert leaves on a full disk, reporting success
    real = os.statvfs

    class Full:
        def __init__(self, st):
            self.f_frsize, self.f_bavail = st.f_frsize, 0

    monkeypatch.setattr(os, "statvfs", lambda p: Full(real(p)))
    with pytest.raises(OSError, match="No space left on device"):
        _parse_xml(net)


def test_a_second_batch_on_one_folder_refuses_in_one_line(tmp_path, capsys):
    out = tmp_path / "r"
    out.mkdir()
    with OutputLock(out, inside=True):
        rc = main(["-q", "regress", str(CFG), "--end", "40", "--init", "random", "--rollout", "cv",
                   "--planner", "replay", "-o", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "another coster-sumo command is writing it" in err[0]
    assert not (out / "results").exists()


# ---------------------------------------------------------------- 5. a SUMO crash is one line, not a dead command

@pytest.mark.parametrize(("command", "where"), [("replay", "coster_sumo.sim.replay.replay"),
                                                ("run", "coster_sumo.pipeline.run.nominal_pass")])
def test_a_sumo_crash_outside_the_variants_is_one_line(tmp_path, command, where):
    """The command as a user starts it, with a libsumo crash (SIGABRT, as a segfault takes its
    process down) injected where it simulates outside the variants."""
    module, name = where.rsplit(".", 1)
    code = (f"import importlib, os, sys; setattr(importlib.import_module({module!r}), {name!r}, "
            "lambda *a, **k: os.abort()); from coster_sumo.cli.command_line import main; sys.exit(main(sys.argv[1:]))")
    args = ["-q", command, str(CFG), *(FAST if command == "run" else []), "-o", str(tmp_path / "o")]
    done = subprocess.run([sys.executable, "-c", code, *args], cwd=REPO, capture_output=True, text=True,
                          timeout=600)
    err = [ln for ln in done.stderr.splitlines() if ln.strip()]
    assert done.returncode == 1 and len(err) == 1, err
    assert f"{command} of {CFG}: stopped, crashed (SIGABRT)" in err[0]
    assert [p.name for p in tmp_path.iterdir()] == []  # no staging folder, no lock
