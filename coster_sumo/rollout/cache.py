"""Rollout training features built once per corpus and memory-mapped (numpy only, no torch).

Building the inputs of an example (:func:`coster_sumo.rollout.data.agent_context`) costs a few
milliseconds of Python; doing it for every batch of every epoch kept training slow. Here every
example of a list of scene files is encoded once, in worker processes, and stored as flat ``.npy``
arrays that training opens with ``mmap_mode="r"``: a corpus larger than memory still trains (the
operating system pages in what a batch touches, with read-ahead turned off: :func:`random_access`)
and a second run starts at once.

Layout of one cache folder (``<root>/rollout-<key>/``), ``E`` examples::

    meta.json           written last: key, counts, the encoding settings (its presence = complete)
    index.npy           (E, 4) int64 scene, agent, t_index, horizon (as ExampleSet.index)
    origin.npy          (E, 3) float64     state.npy     (E, 4) float32
    traj.npy            (E, H, 3) float32  step_mask.npy (E, H) bool     (H = max_horizon)
    map_offset.npy      (E + 1,) int64: the map chunks of example e are rows offset[e]:offset[e+1] of
    map_vec.npy (K, P, 6) float32, map_vec_mask.npy (K, P) bool, map_attr.npy (K, 9) uint8 (one-hot,
    exact as 0/1), map_pos.npy (K, 4) float32, map_mask.npy (K,) bool
    nbr_offset.npy      (E + 1,) int64: likewise the neighbour slots, slot-major:
    nbr.npy (Q, H + 1, 12) float32, nbr_mask.npy (Q, H + 1) bool

Only the chunks and neighbour slots an example uses are stored (the rest of the fixed-size
context is padding); :meth:`CachedExamples.batch` pads them back to the batch's largest, which is
what the model keeps after :func:`coster_sumo.rollout.model.trim_padding`: the model sees the
same numbers as with :meth:`coster_sumo.rollout.data.ExampleSet.batch`.

The key hashes the scene files (names and contents), the encoding settings of
:class:`~coster_sumo.rollout.config.RolloutConfig` (not the model's width; the agent class but for
vehicles), ``min_steps`` and
:data:`FEATURE_VERSION`: editing a scene or a setting builds a new folder; nothing is reused
wrongly. Folders are built under a temporary name and renamed when complete.
"""

from __future__ import annotations

import hashlib
import json
import mmap
import os
import shutil
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.errors import InputError
from coster_sumo.infra.atomic import write_json
from coster_sumo.rollout.config import RolloutConfig
from coster_sumo.rollout.data import (
    ROLLOUT_HZ,
    agent_context,
    build_cache,
    enumerate_examples,
    reverse_targets,
)

FEATURE_VERSION = 1
CACHE_DIR_NAME = ".cache"
CACHE_FORMAT = "coster-sumo-rollout-features"  # meta.json's "format"
ENCODING_FIELDS = ("max_horizon", "max_neighbors", "neighbor_select_radius_m", "max_map_chunks", "map_radius_m",
                   "lane_spacing_m", "chunk_vectors", "pos_scale_m", "vel_scale_mps")
# name -> dtype; "per example" arrays first, then the ragged map chunks and neighbour slots
_EXAMPLE_FIELDS = {"index": np.int64, "origin": np.float64, "state": np.float32, "traj": np.float32,
                   "step_mask": np.bool_}
_MAP_FIELDS = {"map_vec": np.float32, "map_vec_mask": np.bool_, "map_attr": np.uint8, "map_pos": np.float32,
               "map_mask": np.bool_}
_NBR_FIELDS = {"nbr": np.float32, "nbr_mask": np.bool_}
_ALL_FIELDS = {**_EXAMPLE_FIELDS, **_MAP_FIELDS, **_NBR_FIELDS}


@dataclass
class CacheCounts:
    """Rows written so far: examples, map chunks and neighbour slots (the leading sizes of the
    per-example, map and neighbour arrays)."""

    examples: int = 0
    map_chunks: int = 0
    neighbour_slots: int = 0


@dataclass(frozen=True)
class CacheMeta:
    """A cache folder's ``meta.json``: its key, the encoding settings (:func:`encoding_settings`),
    how many scene files it encoded and how many of them had examples, and the row counts."""

    key: str
    settings: dict[str, Any]
    scene_files: int
    scenes: int
    counts: CacheCounts

    def to_json(self) -> dict[str, Any]:
        return {"format": CACHE_FORMAT, "key": self.key, "settings": self.settings, "scene_files": self.scene_files,
                "scenes": self.scenes, "examples": self.counts.examples, "map_chunks": self.counts.map_chunks,
                "neighbour_slots": self.counts.neighbour_slots}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> CacheMeta:
        return cls(key=d["key"], settings=d["settings"], scene_files=d["scene_files"], scenes=d["scenes"],
                   counts=CacheCounts(d["examples"], d["map_chunks"], d["neighbour_slots"]))


def encoding_settings(cfg: RolloutConfig, min_steps: int) -> dict[str, Any]:
    """What the stored features depend on (besides the scenes): the class of the tracks too, but for
    vehicles (absent from ``cfg.to_dict()``: a vehicle cache keeps the key it had before)."""
    d = cfg.to_dict()
    return {"version": FEATURE_VERSION, "min_steps": int(min_steps),
            **{k: d[k] for k in (*ENCODING_FIELDS, "agent_class") if k in d}}


def files_digest(paths: Sequence[Path]) -> str:
    """sha256 over the names and contents of ``paths`` (in order)."""
    h = hashlib.sha256()
    for p in paths:
        h.update(Path(p).name.encode() + b"\0")
        with open(p, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
        h.update(b"\0")
    return h.hexdigest()


def cache_key(paths: Sequence[Path], cfg: RolloutConfig, min_steps: int) -> str:
    """The folder key of a cache of ``paths`` (24 hex digits)."""
    settings = json.dumps(encoding_settings(cfg, min_steps), sort_keys=True)
    return hashlib.sha256((files_digest(paths) + settings).encode()).hexdigest()[:24]


def default_cache_root(paths: Sequence[Path]) -> Path:
    """``DATASET/.cache`` for scenes in ``DATASET/scenes/`` (else ``.cache`` in the scenes' folder)."""
    folder = Path(paths[0]).resolve().parent
    if folder.name == "scenes":
        folder = folder.parent
    return folder / CACHE_DIR_NAME


def encode_scene_file(path: Path, cfg: RolloutConfig, min_steps: int) -> dict[str, np.ndarray] | None:
    """Every example of one scene file, in the stored layout (None: the scene has no example).
    ``index[:, 0]`` is 0; the caller numbers the scenes."""
    from coster_sumo.core.scene import resample
    from coster_sumo.formats.scene_file import load_scene

    low = resample(load_scene(path), ROLLOUT_HZ)
    examples = enumerate_examples(low, cfg, min_steps=min_steps)
    if not examples:
        return None
    cache = build_cache(low, cfg)
    h_max = cfg.max_horizon
    cols: dict[str, list[np.ndarray]] = {k: [] for k in _ALL_FIELDS}
    map_count, nbr_count = [], []
    for a, t, h in examples:
        ctx = agent_context(cache, a, t, h, cfg)
        traj, m = reverse_targets(low, a, t, h_max)
        m[h:] = False
        cols["index"].append(np.array([0, a, t, h], np.int64))
        cols["origin"].append(ctx.origin)
        cols["state"].append(ctx.state)
        cols["traj"].append(traj)
        cols["step_mask"].append(m)
        k = _used(ctx.map_mask | ctx.map_attr.any(axis=1))  # chunks with data (masked ones keep attributes)
        cols["map_vec"].append(ctx.map_vec[:k])
        cols["map_vec_mask"].append(ctx.map_vec_mask[:k])
        cols["map_attr"].append(ctx.map_attr[:k].astype(np.uint8))
        cols["map_pos"].append(ctx.map_pos[:k])
        cols["map_mask"].append(ctx.map_mask[:k])
        n = _used(np.asarray(ctx.nbr_mask.any(axis=0)))
        nbr = np.zeros((n, h_max + 1, ctx.nbr.shape[-1]), np.float32)
        nbr_mask = np.zeros((n, h_max + 1), bool)
        nbr[:, :h + 1] = ctx.nbr[:, :n].transpose(1, 0, 2)
        nbr_mask[:, :h + 1] = ctx.nbr_mask[:, :n].T
        cols["nbr"].append(nbr)
        cols["nbr_mask"].append(nbr_mask)
        map_count.append(k)
        nbr_count.append(n)
    out = {}
    for name, parts in cols.items():
        out[name] = np.stack(parts) if name in _EXAMPLE_FIELDS else np.concatenate(parts)
        out[name] = out[name].astype(_ALL_FIELDS[name], copy=False)
    out["map_count"] = np.asarray(map_count, np.int64)
    out["nbr_count"] = np.asarray(nbr_count, np.int64)
    return out


def _used(mask: np.ndarray) -> int:
    """1 + the last True index of a 1-D mask (0 if none)."""
    idx = np.flatnonzero(mask)
    return int(idx[-1]) + 1 if len(idx) else 0


def _encode_job(job: tuple[str, dict[str, Any], int]) -> dict[str, np.ndarray] | None:
    path, cfg_dict, min_steps = job
    return encode_scene_file(Path(path), RolloutConfig.from_dict(cfg_dict), min_steps)


def _npy_from_raw(raw: Path, out: Path, dtype: Any, shape: tuple[int, ...]) -> None:
    """Prefix the raw bytes of ``raw`` with a .npy header into ``out`` (then delete ``raw``)."""
    with open(out, "wb") as f:
        np.lib.format.write_array_header_1_0(f, {"descr": np.lib.format.dtype_to_descr(np.dtype(dtype)),
                                                 "fortran_order": False, "shape": shape})
        with open(raw, "rb") as src:
            shutil.copyfileobj(src, f, 1 << 22)
    raw.unlink()


def build_feature_cache(paths: Sequence[Path], cfg: RolloutConfig, min_steps: int, folder: Path,
                        workers: int = 0, progress: Callable[[Iterable[Any], int], Iterable[Any]] | None = None
                        ) -> Path:
    """Encode every example of ``paths`` into ``folder`` (see the module docstring).

    Scenes are encoded in ``workers`` processes (0: one per core; 1: in this process) and written in
    file order as they come, so memory holds a few scenes at a time whatever the corpus size.
    """
    folder = Path(folder)
    tmp = folder.with_name(f".{folder.name}.{os.getpid()}.tmp")
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir(parents=True)
    workers = workers if workers > 0 else (os.cpu_count() or 1)
    workers = min(workers, max(1, len(paths) // 4))  # a pool costs about a second to start
    jobs = [(str(p), cfg.to_dict(), int(min_steps)) for p in paths]
    raw = {name: open(tmp / f"{name}.raw", "wb") for name in _ALL_FIELDS}  # noqa: SIM115 (closed below)
    inner: dict[str, tuple[int, ...]] = {}
    rows = CacheCounts()
    map_off: list[np.ndarray] = [np.zeros(1, np.int64)]
    nbr_off: list[np.ndarray] = [np.zeros(1, np.int64)]
    num_scenes = 0
    try:
        if workers > 1:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor

            # fork: no re-import of the caller's main module (scripts need no __main__ guard); the
            # workers use numpy only
            method = "fork" if "fork" in mp.get_all_start_methods() else "spawn"
            pool = ProcessPoolExecutor(workers, mp_context=mp.get_context(method))
            results: Iterable[dict[str, np.ndarray] | None] = pool.map(_encode_job, jobs)
        else:
            pool = None
            results = (_encode_job(j) for j in jobs)
        if progress is not None:
            results = progress(results, len(jobs))
        try:
            for res in results:
                if res is None:
                    continue
                res["index"][:, 0] = num_scenes
                num_scenes += 1
                for name in _ALL_FIELDS:
                    a = np.ascontiguousarray(res[name])
                    inner.setdefault(name, a.shape[1:])
                    raw[name].write(a.tobytes())
                map_off.append(rows.map_chunks + np.cumsum(res["map_count"]))
                nbr_off.append(rows.neighbour_slots + np.cumsum(res["nbr_count"]))
                rows.examples += len(res["index"])
                rows.map_chunks += int(res["map_count"].sum())
                rows.neighbour_slots += int(res["nbr_count"].sum())
        finally:
            if pool is not None:
                pool.shutdown(cancel_futures=True)
    finally:
        for f in raw.values():
            f.close()
    p, h = cfg.chunk_vectors, cfg.max_horizon
    default_inner = {"index": (4,), "origin": (3,), "state": (4,), "traj": (h, 3), "step_mask": (h,),
                     "map_vec": (p, 6), "map_vec_mask": (p,), "map_attr": (9,), "map_pos": (4,), "map_mask": (),
                     "nbr": (h + 1, 12), "nbr_mask": (h + 1,)}
    for name, dtype in _ALL_FIELDS.items():
        lead = (rows.examples if name in _EXAMPLE_FIELDS else rows.map_chunks if name in _MAP_FIELDS
                else rows.neighbour_slots)
        _npy_from_raw(tmp / f"{name}.raw", tmp / f"{name}.npy", dtype, (lead, *inner.get(name, default_inner[name])))
    np.save(tmp / "map_offset.npy", np.concatenate(map_off))
    np.save(tmp / "nbr_offset.npy", np.concatenate(nbr_off))
    meta = CacheMeta(key=folder.name, settings=encoding_settings(cfg, min_steps), scene_files=len(paths),
                     scenes=num_scenes, counts=rows)
    write_json(tmp / "meta.json", meta.to_json())
    try:
        os.replace(tmp, folder)
    except OSError:  # another process finished the same cache first: keep theirs
        if not (folder / "meta.json").is_file():
            raise
        shutil.rmtree(tmp, ignore_errors=True)
    return folder


def random_access(array: np.ndarray) -> None:
    """Tell the kernel that ``array``'s file mapping is read at random (``MADV_RANDOM``): no
    read-ahead. A batch touches a few kB at each of a few hundred random places; with the read-ahead
    of a page fault (8 MB on the project's VM) a batch of 256 read about 1 GB from a cache larger
    than memory instead of 2.6 MB, and training waited for the disk (``bench/RESULTS.md``, "A cache
    larger than memory"). A cache that fits in memory is paged in once either way. No-op where the
    platform has no madvise or the array is not a file mapping."""
    mapping = getattr(array, "_mmap", None)
    advice = getattr(mmap, "MADV_RANDOM", None)
    if mapping is not None and advice is not None:
        try:
            mapping.madvise(advice)
        except (OSError, ValueError):  # advice is only a hint: reading still works without it
            pass


class CachedExamples:
    """Examples read from a feature cache folder; a drop-in for
    :class:`~coster_sumo.rollout.data.ExampleSet` in training and :func:`cvae_errors` (not for the
    baselines, which need the scenes)."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        self.meta = CacheMeta.from_json(json.loads((self.folder / "meta.json").read_text()))
        names = [*_ALL_FIELDS, "map_offset", "nbr_offset"]
        self.arrays = {n: np.load(self.folder / f"{n}.npy", mmap_mode="r") for n in names}
        # the small arrays every batch looks up are read into memory once; the rest stay mapped
        self.map_offset = np.array(self.arrays["map_offset"])
        self.nbr_offset = np.array(self.arrays["nbr_offset"])
        self.index = np.array(self.arrays["index"])
        for name in _ALL_FIELDS:
            if name != "index":
                random_access(self.arrays[name])

    def __len__(self) -> int:
        return len(self.index)

    def _ragged(self, offset: np.ndarray, rows: np.ndarray, names: Iterable[str]
                ) -> dict[str, np.ndarray]:
        start = offset[rows]
        count = offset[rows + 1] - start
        width = max(1, int(count.max()) if len(count) else 1)
        j = np.arange(width)
        valid = j[None, :] < count[:, None]  # (B, width)
        flat = np.where(valid, start[:, None] + j, 0).ravel()
        out = {}
        for name in names:
            src = self.arrays[name]
            if len(src) == 0:
                out[name] = np.zeros((len(rows), width, *src.shape[1:]), src.dtype)
                continue
            a = src[flat].reshape(len(rows), width, *src.shape[1:])
            a[~valid] = 0
            out[name] = a
        return out

    def batch(self, rows: Sequence[int] | np.ndarray, cfg: RolloutConfig, horizon: int | None = None
              ) -> dict[str, np.ndarray]:
        """Contexts and targets of ``rows`` as :meth:`ExampleSet.batch` gives them, map chunks and
        neighbour slots padded to the batch's largest instead of to the configured maximum."""
        rows = np.asarray(rows, dtype=np.int64)
        sel = self.index[rows]
        h_pad = int(sel[:, 3].max()) if horizon is None else int(horizon)
        a = self.arrays
        out = {name: np.asarray(a[name][rows]) for name in ("state", "origin")}
        out.update(self._ragged(self.map_offset, rows, _MAP_FIELDS))
        out["map_attr"] = out["map_attr"].astype(np.float32)
        nb = self._ragged(self.nbr_offset, rows, _NBR_FIELDS)
        out["nbr"] = np.ascontiguousarray(nb["nbr"][:, :, :h_pad + 1].transpose(0, 2, 1, 3))
        out["nbr_mask"] = np.ascontiguousarray(nb["nbr_mask"][:, :, :h_pad + 1].transpose(0, 2, 1))
        if out["nbr"].shape[1] < h_pad + 1:  # a horizon beyond max_horizon: masked steps
            pad = h_pad + 1 - out["nbr"].shape[1]
            for k in ("nbr", "nbr_mask"):
                out[k] = np.concatenate([out[k], np.zeros((len(rows), pad, *out[k].shape[2:]), out[k].dtype)], 1)
        traj, mask = np.asarray(a["traj"][rows]), np.asarray(a["step_mask"][rows])
        if traj.shape[1] < h_pad:
            traj = np.concatenate([traj, np.zeros((len(rows), h_pad - traj.shape[1], 3), traj.dtype)], 1)
            mask = np.concatenate([mask, np.zeros((len(rows), h_pad - mask.shape[1]), bool)], 1)
        out["traj"] = np.ascontiguousarray(traj[:, :h_pad])
        out["step_mask"] = np.ascontiguousarray(mask[:, :h_pad])
        return out


def cached_examples(paths: Sequence[Path], cfg: RolloutConfig, min_steps: int, root: str | Path | None = None,
                    workers: int = 0, progress: Callable[[Iterable[Any], int], Iterable[Any]] | None = None
                    ) -> CachedExamples:
    """The examples of ``paths`` from their feature cache under ``root`` (default
    :func:`default_cache_root`), built first when missing."""
    paths = [Path(p) for p in paths]
    if not paths:
        raise InputError("no scene files to encode")
    root = Path(root) if root is not None else default_cache_root(paths)
    folder = root / f"rollout-{cache_key(paths, cfg, min_steps)}"
    if not (folder / "meta.json").is_file():
        build_feature_cache(paths, cfg, min_steps, folder, workers=workers, progress=progress)
    return CachedExamples(folder)
