"""Recognise TensorFlow ``tf.train.Example`` records, the other WOMD release encoding (and refuse them).

WOMD is published twice: as ``Scenario`` protobufs (what :mod:`converters.womd` reads) and as
"tf_example" TFRecords, where each record is a ``tf.train.Example`` of fixed-size tensors named
``roadgraph_samples/*``, ``state/*``, ``traffic_light_state/*`` and ``scenario/id`` (docs/womd.md,
"Other encodings of WOMD"). A tf.Example can even parse as a (garbage) ``Scenario``: its field 1
reads as packed timestamps whenever its length is a multiple of 8. So every record is sniffed
first; the wire layout is

    Example  { Features features = 1; }
    Features { map<string, Feature> feature = 1; }   // entries: key = 1 (string), value = 2 (Feature)

and a record made only of that layout, with text keys, is an Example. Only the keys are looked at.
"""

from __future__ import annotations

from collections.abc import Iterator

WOMD_TF_EXAMPLE_PREFIXES = ("roadgraph_samples/", "state/", "traffic_light_state/", "scenario/")
_LEN = 2  # wire type of length-delimited fields
_MAX_KEYS = 100_000
_ONE = frozenset({1})
_KEY_VALUE = frozenset({1, 2})


def _varint(buf: bytes, pos: int) -> tuple[int, int]:
    """(value, next position); ValueError past the end or beyond 10 bytes."""
    value = shift = 0
    for _ in range(10):
        if pos >= len(buf):
            raise ValueError("truncated varint")
        b = buf[pos]
        pos += 1
        value |= (b & 0x7F) << shift
        if not b & 0x80:
            return value, pos
        shift += 7
    raise ValueError("varint too long")


def _fields(buf: bytes, allowed: frozenset[int]) -> Iterator[tuple[int, bytes]]:
    """(field number, payload) of a message made only of length-delimited fields numbered ``allowed``.

    ValueError at the first field that is not (a Scenario fails within its first few fields).
    """
    pos = count = 0
    while pos < len(buf):
        tag, pos = _varint(buf, pos)
        if tag & 7 != _LEN or tag >> 3 not in allowed:
            raise ValueError("not an Example field")
        length, pos = _varint(buf, pos)
        if pos + length > len(buf):
            raise ValueError("field runs past the end")
        yield tag >> 3, buf[pos:pos + length]
        pos += length
        count += 1
        if count > _MAX_KEYS:
            raise ValueError("too many fields")


def example_keys(data: bytes) -> list[str] | None:
    """The feature names when ``data`` is a serialized ``tf.train.Example``, else None."""
    if data[:1] != b"\x0a":  # field 1, length-delimited: how every non-empty Example starts
        return None
    keys: list[str] = []
    try:
        for _, features in _fields(data, _ONE):
            for _, entry in _fields(features, _ONE):
                parts = dict(_fields(entry, _KEY_VALUE))
                if 1 not in parts:
                    return None
                keys.append(parts[1].decode("utf-8"))
    except (ValueError, UnicodeDecodeError):
        return None
    return keys or None


def describe_example(keys: list[str]) -> str:
    """Why a tf.Example record is refused, and what to use instead (one line)."""
    if any(k.startswith(WOMD_TF_EXAMPLE_PREFIXES) for k in keys):
        return ("a WOMD tf.Example record (the \"tf_example\" release: roadgraph_samples/*, state/*, "
                "traffic_light_state/* tensors), which coster-sumo does not read; use the WOMD "
                "\"scenario\" release (Scenario protobuf TFRecords) or a ScenarioNet .pkl of the same scene")
    shown = ", ".join(sorted(keys)[:3])
    return (f"a TensorFlow tf.Example record (features {shown}, ...), not a WOMD Scenario; coster-sumo reads "
            "WOMD Scenario TFRecords and ScenarioNet .pkl files")
