"""The restricted unpickler of ScenarioNet / MetaDrive pickles (:mod:`converters.scenarionet`).

**Security**: a pickle names the Python callables that rebuild its objects, so a plain
``pickle.load`` runs whatever a crafted file asks for. This module never does: it loads through
:class:`RestrictedUnpickler`, which resolves only the globals a scenario description is made of
(builtin containers and scalars, ``collections.defaultdict`` / ``OrderedDict``, numpy arrays, dtypes
and scalars with numpy's own rebuild helpers). Any other global ends the read with one line naming
the file and the refused global (docs/womd.md, "Hostile inputs"). What it loads is then checked by
:func:`converters.scenarionet.description_to_scene`.
"""

from __future__ import annotations

import _compat_pickle
import collections
import importlib
import io
import pickle
import pickletools
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.errors import InputError

PICKLE_MAGIC = b"\x80"  # pickle protocol >= 2 starts with the PROTO opcode
MAX_RECONSTRUCT_ITEMS = 1 << 20  # numpy's rebuild helper starts from an empty array; allow small ones


class RefusedGlobal(pickle.UnpicklingError):
    """A pickle asked for a global outside :data:`ALLOWED_GLOBALS`."""

    def __init__(self, module: str, name: str) -> None:
        super().__init__(f"{module}.{name}")
        self.module, self.name = module, name


def _numpy_attr(modules: tuple[str, ...], name: str) -> Callable[..., Any] | None:
    for mod in modules:
        try:
            return getattr(importlib.import_module(mod), name)  # type: ignore[no-any-return]
        except (ImportError, AttributeError):
            continue
    return None


def _latin1_encode(text: Any, encoding: str = "utf-8", errors: str = "strict") -> bytes:
    """What protocol-2 pickles use to rebuild ``bytes``; only the latin-1 spelling is accepted."""
    if not isinstance(text, str) or encoding.replace("_", "-").lower() not in ("latin1", "latin-1"):
        raise pickle.UnpicklingError(f"_codecs.encode with encoding {encoding!r}")
    return text.encode("latin-1", errors if errors == "strict" else "strict")


class _NdarrayName:
    """What the name ``numpy.ndarray`` resolves to: only numpy's rebuild helper may use it.

    A pickle could otherwise call ``ndarray((10**10,))`` directly and reserve any amount of memory.
    """

    def __new__(cls, *args: Any, **kwargs: Any) -> Any:
        raise pickle.UnpicklingError("numpy.ndarray called directly")


def _safe_builtin(t: type) -> Any:
    """``t`` for the unpickler: its constructor, refusing the calls that could exhaust memory or
    look up a codec (``bytes(10**10)``, ``str(b, encoding)``)."""
    def build(*args: Any) -> Any:
        if t in (bytes, str) and (len(args) > 1 or any(isinstance(a, int) for a in args)):
            raise pickle.UnpicklingError(f"{t.__name__} called with {len(args)} arguments")
        return t(*args)

    build.__name__ = build.__qualname__ = t.__name__
    return build


def _allowed_globals() -> dict[tuple[str, str], Any]:
    """(module, name) -> the object handed to the unpickler. Nothing else resolves."""
    multiarray = ("numpy._core.multiarray", "numpy.core.multiarray")
    numeric = ("numpy._core.numeric", "numpy.core.numeric")
    reconstruct = _numpy_attr(multiarray, "_reconstruct")
    scalar = _numpy_attr(multiarray, "scalar")
    frombuffer = _numpy_attr(numeric, "_frombuffer")

    def safe_reconstruct(subtype: Any, shape: Any, dtype: Any) -> Any:
        # numpy pickles an array as _reconstruct(ndarray, (0,), b"b") followed by its state
        if subtype is not _NdarrayName or int(np.prod(np.asarray(shape, np.int64))) > MAX_RECONSTRUCT_ITEMS:
            raise pickle.UnpicklingError("numpy _reconstruct with unexpected arguments")
        assert reconstruct is not None
        return reconstruct(np.ndarray, shape, dtype)

    out: dict[tuple[str, str], Any] = {
        ("builtins", t.__name__): _safe_builtin(t)
        for t in (bool, int, float, complex, str, bytes, list, tuple, dict, set, frozenset)}
    out[("collections", "OrderedDict")] = collections.OrderedDict
    out[("collections", "defaultdict")] = collections.defaultdict
    out[("_codecs", "encode")] = _latin1_encode
    out[("numpy", "ndarray")] = _NdarrayName
    out[("numpy", "dtype")] = np.dtype
    for mod in (*multiarray, *numeric):
        if reconstruct is not None and mod in multiarray:
            out[(mod, "_reconstruct")] = safe_reconstruct
        if scalar is not None and mod in multiarray:
            out[(mod, "scalar")] = scalar
        if frombuffer is not None and mod in numeric:
            out[(mod, "_frombuffer")] = frombuffer
    return out


ALLOWED_GLOBALS: dict[tuple[str, str], Any] = _allowed_globals()


class RestrictedUnpickler(pickle.Unpickler):
    """``pickle.Unpickler`` that resolves only :data:`ALLOWED_GLOBALS` (no other code can run)."""

    def find_class(self, module: str, name: str) -> Any:
        # protocol 2 pickles spell Python 2 names (__builtin__.set); map them as pickle itself does.
        # The mapped name is then checked like any other.
        if (module, name) in _compat_pickle.NAME_MAPPING:
            module, name = _compat_pickle.NAME_MAPPING[(module, name)]
        else:
            module = _compat_pickle.IMPORT_MAPPING.get(module, module)
        try:
            return ALLOWED_GLOBALS[(module, name)]
        except KeyError:
            raise RefusedGlobal(module, name) from None

    def persistent_load(self, pid: Any) -> Any:
        raise pickle.UnpicklingError("persistent ids are not supported")


def printable(text: str, limit: int = 80) -> str:
    """``text`` shortened, with control characters escaped (one line for any input)."""
    out = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text[:limit])
    return out + ("..." if len(text) > limit else "")


_MEMO_PUTS = frozenset({"PUT", "BINPUT", "LONG_BINPUT"})


def check_opcodes(data: bytes) -> None:
    """Walk the opcode stream once before loading: a malformed stream, or a memo index beyond the
    opcodes read so far (the C unpickler sizes its memo table to the largest index: a 5-byte
    ``LONG_BINPUT 0x7fffffff`` would make it allocate 16 GB), is an UnpicklingError."""
    for count, (op, arg, _) in enumerate(pickletools.genops(data)):
        if op.name in _MEMO_PUTS and int(str(arg)) > count:
            raise pickle.UnpicklingError(f"memo index {arg} at opcode {count}")


def load_pickle(path: str | Path) -> Any:
    """The object in a pickle, loaded with :class:`RestrictedUnpickler`; one-line InputError otherwise."""
    path = Path(path)
    try:
        data = path.read_bytes()  # from memory: a damaged length field cannot make a huge read buffer
    except OSError as exc:
        raise InputError(f"{path}: cannot open ({exc.strerror or exc})") from None
    try:
        check_opcodes(data)
        return RestrictedUnpickler(io.BytesIO(data)).load()
    except OSError as exc:
        raise InputError(f"{path}: cannot open ({exc.strerror or exc})") from None
    except RefusedGlobal as exc:
        raise InputError(f"{path}: refused: the pickle asks for the global "
                         f"{printable(exc.module)}.{printable(exc.name)}, which is not part of a ScenarioNet "
                         "scenario (only containers, numbers, strings and numpy arrays are loaded)") from None
    except RecursionError:
        raise InputError(f"{path}: not a ScenarioNet pickle (nested too deeply)") from None
    except MemoryError:
        raise InputError(f"{path}: not a ScenarioNet pickle (asks for more memory than there is)") from None
    except Exception as exc:  # UnpicklingError, EOFError, ValueError, ... of a damaged file
        msg = printable(" ".join(str(exc).split()), 160)
        raise InputError(f"{path}: not a ScenarioNet pickle ({type(exc).__name__}: {msg})") from None
