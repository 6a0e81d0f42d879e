"""Pack a share of the corpus, and the wheels the CLI lacks there, for training on a lent GPU machine.

Usage: python bench/pack_for_device.py CORPUS [--out .device] [--max-mb 36] [--seed 0] [--no-wheels]
                                        [--agent-class vehicle|pedestrian|cyclist]

The device machine (``device`` tool) receives only the working tree, at most 64 MiB with what is
carried, and reaches no package index. The corpus is ten times that (its clips hold 91 steps at
10 Hz; the rollout trains at 2 Hz), so this script writes a seeded share of ``CORPUS/scenes`` at
2 Hz (:func:`coster_sumo.core.scene.resample`, the same steps the training keeps: the features are
those of the full clips) into ``OUT/scenes`` until ``--max-mb`` is reached. Training and
validation files keep their split (it hashes the file name). With ``--agent-class`` only the
scenes that hold an agent of that class are packed (a pedestrian model learns nothing from a
freeway clip without one). It also downloads the wheels of the
packages the CLI imports that the machine's Python 3.12 image lacks (shapely, defusedxml, and
google-crc32c for the WOMD readers that ``eval rollout`` imports) into ``OUT/whl``, adds
``/OUT/`` to ``.git/info/exclude`` and writes ``OUT/pack.json`` (what was packed).
``bench/device_rollout.sh`` is the device command that uses it (``models/rollout.md``, "Training
on a lent GPU").
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from coster_sumo.core.scene import resample
from coster_sumo.data.dataset import list_scenes
from coster_sumo.formats.scene_file import load_scene, save_scene
from coster_sumo.rollout.config import AGENT_CLASSES
from coster_sumo.rollout.data import ROLLOUT_HZ

REPO = Path(__file__).resolve().parents[1]
# what the device's image lacks among the CLI's imports (its torch, numpy, scipy, matplotlib and
# tqdm are there): the versions this project's CI installs for Python 3.11, built for 3.12
WHEELS = ("shapely==2.2.0", "defusedxml==0.7.1", "google-crc32c==1.9.0")
PLATFORMS = ("manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64")


def exclude(folder: Path) -> None:
    """Keep ``folder`` (inside the repository) out of git, so that only ``carry`` moves it."""
    info = REPO / ".git" / "info" / "exclude"
    line = f"/{folder.resolve().relative_to(REPO)}/"
    if info.parent.is_dir() and not (info.is_file() and line in info.read_text().splitlines()):
        with info.open("a") as fh:
            fh.write(line + "\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("corpus", type=Path)
    ap.add_argument("--out", type=Path, default=REPO / ".device")
    ap.add_argument("--max-mb", type=float, default=36.0, help="scene files at most (MiB, %(default)s)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-wheels", action="store_true", help="pack the scenes only")
    ap.add_argument("--agent-class", choices=sorted(AGENT_CLASSES), default=None,
                    help="only scenes with an agent of this class (default: every scene)")
    args = ap.parse_args()
    files = list_scenes(args.corpus)
    if not files:
        raise SystemExit(f"{args.corpus}: no scenes")
    out = args.out
    (out / "scenes").mkdir(parents=True, exist_ok=True)
    if out.resolve().is_relative_to(REPO):
        exclude(out)
    order = np.random.default_rng(args.seed).permutation(len(files))
    budget, used, packed = args.max_mb * 2**20, 0, []
    for i in order:
        src = files[int(i)]
        scene = load_scene(src)
        if args.agent_class and not (scene.tracks.object_type == AGENT_CLASSES[args.agent_class]).any():
            continue
        dst = out / "scenes" / src.name
        save_scene(resample(scene, ROLLOUT_HZ), dst)
        size = dst.stat().st_size
        if used + size > budget:
            dst.unlink()
            break
        used += size
        packed.append(src.name)
    wheels: list[str] = []
    if not args.no_wheels:
        (out / "whl").mkdir(exist_ok=True)
        cmd = [sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary=:all:", "--python-version",
               "3.12", "--implementation", "cp", *[a for p in PLATFORMS for a in ("--platform", p)],
               "-d", str(out / "whl"), *WHEELS]
        subprocess.run(cmd, check=True)
        wheels = sorted(p.name for p in (out / "whl").glob("*.whl"))
    record = {"corpus": str(args.corpus.resolve()), "scenes_in_corpus": len(files), "scenes": len(packed),
              "share": len(packed) / len(files), "mb": used / 2**20, "hz": ROLLOUT_HZ, "seed": args.seed,
              "agent_class": args.agent_class,
              "wheels": wheels, "files": sorted(packed)}
    (out / "pack.json").write_text(json.dumps(record, indent=1))
    print(f"{len(packed)} of {len(files)} scenes ({100 * len(packed) / len(files):.0f} %), {used / 2**20:.1f} MiB "
          f"at {ROLLOUT_HZ:g} Hz in {out / 'scenes'}; wheels: {', '.join(wheels) or 'none'}")


if __name__ == "__main__":
    main()
