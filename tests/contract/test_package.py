"""The built wheel is a working tool from any folder: weights and demo networks travel inside it,
and it installs one import package (``coster_sumo``), no top-level ``converters``.

The wheel is installed into a fresh virtual environment without its dependencies; those are taken
from the environment running the tests (a ``.pth`` file adds its site-packages), so the test needs
no network and no second copy of torch and SUMO.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import venv
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
pytestmark = [pytest.mark.slow, pytest.mark.sumo]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    build = tmp_path_factory.mktemp("build")
    src = build / "src"  # a copy: building in place would leave build/ and *.egg-info in the checkout
    shutil.copytree(REPO, src, ignore=shutil.ignore_patterns(".venv", ".git", "out", "build", "dist", "*.egg-info",
                                                             "__pycache__", ".*_cache"))
    cmd = [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(out), str(src)]
    if subprocess.run([*cmd, "--no-build-isolation"], capture_output=True).returncode != 0:
        subprocess.run(cmd, check=True, capture_output=True)  # no setuptools with bdist_wheel here: pip fetches one
    (whl,) = out.glob("coster_sumo-*.whl")
    return whl


def test_wheel_holds_one_package_with_weights_and_networks(wheel: Path) -> None:
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names if not n.startswith("coster_sumo-")}
    assert tops == {"coster_sumo"}
    for f in ("prior.pt", "rollout.pt", "rollout_nodsa.pt", "vocab.npz"):
        assert f"coster_sumo/models/{f}" in names
    assert "coster_sumo/networks/intersection/intersection.sumocfg" in names
    assert "coster_sumo/converters/womd.py" in names


def test_installed_wheel_runs_the_demo_from_an_empty_folder(wheel: Path, tmp_path: Path) -> None:
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    py = env_dir / "bin" / "python"
    site = Path(subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               check=True, capture_output=True, text=True).stdout.strip())
    (site / "test_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")  # torch, SUMO, ...
    subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "-q", "--no-deps", str(wheel)],
                   check=True, capture_output=True)
    empty = tmp_path / "elsewhere"
    empty.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "SUMO_HOME")}
    demo = subprocess.run([str(env_dir / "bin" / "coster-sumo"), "--quiet", "demo", "--variants", "1", "-o", "out"],
                          cwd=empty, env=env, capture_output=True, text=True, timeout=600)
    assert demo.returncode == 0, demo.stderr[-2000:]
    summary = empty / "out" / "summary.json"
    assert summary.is_file() and (empty / "out" / "overview.png").is_file()
    assert (empty / "out" / "variants" / "0" / "render.png").is_file()
    where = subprocess.run([str(py), "-c", "import coster_sumo, coster_sumo.infra.weights as w; "
                                           "print(coster_sumo.__file__); print(w.shipped_models_dir())"],
                           cwd=empty, env=env, capture_output=True, text=True, check=True).stdout.split()
    assert all(str(env_dir) in p for p in where), where  # the installed copy, not the checkout
    no_top_level = subprocess.run([str(py), "-c", "import converters"], cwd=empty, env=env, capture_output=True)
    assert no_top_level.returncode != 0


def _command_lines() -> list[list[str]]:
    """Every subcommand of the CLI, as the words that name it (``["corpus", "build"]``)."""
    import argparse

    from coster_sumo.cli.command_line import build_parser

    def below(parser: argparse.ArgumentParser, words: list[str]) -> list[list[str]]:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs:
            return [words]
        return [w for name, p in subs[0].choices.items() for w in below(p, [*words, name])]

    return below(build_parser(), [])


def test_a_plain_install_starts_every_command(wheel: Path, tmp_path: Path) -> None:
    """``pip install coster-sumo`` with its declared dependencies only (no extras, torch's CPU build
    first as the setup scripts do), in an environment of its own: every command's --help and the
    demo run; a command that needs an extra says which, in one line. Needs the package index."""
    env_dir = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(env_dir)], check=True, capture_output=True)
    pip = [str(env_dir / "bin" / "python"), "-m", "pip", "install", "-q"]
    for what in (["torch==2.13.0"], [str(wheel)]):
        got = subprocess.run([*pip, *what], capture_output=True, text=True, timeout=1800)
        assert got.returncode == 0, got.stderr[-2000:]
    listed = subprocess.run([*pip[:-2], "list"], capture_output=True, text=True, check=True).stdout.lower()
    assert not [m for m in ("gymnasium", "stable-baselines3", "ray", "scenariogeneration", "xmlschema")
                if f"\n{m} " in listed]  # really without the extras
    tool = str(env_dir / "bin" / "coster-sumo")
    empty = tmp_path / "elsewhere"
    empty.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "SUMO_HOME")} | {"COSTER_SUMO_SERVER": "off"}
    lines = _command_lines()
    assert ["policy", "train"] in lines and ["scenarios", "build"] in lines
    for words in [[], *lines]:
        got = subprocess.run([tool, *words, "--help"], cwd=empty, env=env, capture_output=True, text=True)
        assert got.returncode == 0 and "usage:" in got.stdout, (words, got.stderr[-1000:])
    demo = subprocess.run([tool, "--quiet", "demo", "--variants", "1", "-o", "out"], cwd=empty, env=env,
                          capture_output=True, text=True, timeout=900)
    assert demo.returncode == 0, demo.stderr[-2000:]
    train = subprocess.run([tool, "policy", "train", "set", "-o", "policy"], cwd=empty, env=env, capture_output=True,
                           text=True)
    err = train.stderr.strip().splitlines()
    assert train.returncode == 2 and len(err) == 1, train.stderr
    assert "pip install 'coster-sumo[rl]'" in err[0]
