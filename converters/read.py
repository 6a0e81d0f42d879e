"""One entry point for scene files, dispatching on content (not on the file name).

- ScenarioNet / MetaDrive pickle (starts with the pickle PROTO opcode ``0x80``; loaded with the
  restricted unpickler of :mod:`converters.scenarionet_pickle`, so no file can make it run code);
- gzip-compressed TFRecord of WOMD ``Scenario`` records (gzip magic ``1f 8b``);
- this project's own ``.npz`` scenes (zip magic ``PK``, see :func:`coster_sumo.formats.scene_file.save_scene`);
- anything else is read as a plain TFRecord of WOMD ``Scenario`` records (a record that is a
  TensorFlow ``tf.Example``, e.g. WOMD's "tf_example" release, is named and refused).

Errors are :class:`~coster_sumo.errors.InputError` with one line naming the file and, for
TFRecords, the record: ``womd.tfrecord: record 3: data CRC mismatch``.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from coster_sumo.core.scene import Scene
from coster_sumo.errors import InputError
from coster_sumo.formats.scene_file import load_scene

from .scenarionet import iter_pickle_scenes
from .scenarionet_pickle import PICKLE_MAGIC
from .tfrecord import GZIP_MAGIC
from .womd import iter_tfrecord_scenes

ZIP_MAGIC = b"PK\x03\x04"


def sniff(path: str | Path) -> str:
    """"pickle", "tfrecord.gz", "npz" or "tfrecord" from the first bytes of the file."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(4)
    except OSError as exc:
        raise InputError(f"{path}: cannot open ({exc.strerror or exc})") from None
    if not head:
        raise InputError(f"{path}: empty file")
    if head[:1] == PICKLE_MAGIC:
        return "pickle"
    if head[:2] == GZIP_MAGIC:
        return "tfrecord.gz"
    if head == ZIP_MAGIC:
        return "npz"
    return "tfrecord"


def iter_scenes(path: str | Path) -> Iterator[Scene]:
    """Every scene in ``path`` (one per TFRecord record; one for a pickle or ``.npz``)."""
    kind = sniff(path)
    if kind == "pickle":
        yield from iter_pickle_scenes(path)
    elif kind == "npz":
        yield load_scene(path)
    else:
        yield from iter_tfrecord_scenes(path)


def read_scenes(path: str | Path) -> list[Scene]:
    """All scenes in ``path``."""
    return list(iter_scenes(path))
