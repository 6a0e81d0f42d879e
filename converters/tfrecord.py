"""TFRecord files without TensorFlow: reader and writer, plain or gzip-compressed.

A file is a sequence of records, each::

    uint64 length (little-endian)
    uint32 masked CRC-32C of the 8 length bytes
    length bytes of data
    uint32 masked CRC-32C of the data

with ``masked(crc) = ((crc >> 15 | crc << 17) + 0xA282EAD8) & 0xffffffff``. Both CRCs are checked.
Gzip-compressed files (TensorFlow's ``compression_type="GZIP"``) are detected by their magic bytes,
whatever their name. Every problem raises :class:`~coster_sumo.errors.InputError` with one line
naming the file and the record: ``womd.tfrecord: record 3: data CRC mismatch``.
"""

from __future__ import annotations

import gzip as gzip_module
import struct
import zlib
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import BinaryIO

import google_crc32c

from coster_sumo.errors import InputError

GZIP_MAGIC = b"\x1f\x8b"
_MASK_DELTA = 0xA282EAD8
_HEADER = 12  # uint64 length + uint32 length CRC
_FOOTER = 4  # uint32 data CRC


def masked_crc32c(data: bytes | memoryview) -> int:
    """TFRecord's masked CRC-32C of ``data``."""
    crc = google_crc32c.value(bytes(data))
    return (((crc >> 15) | (crc << 17)) + _MASK_DELTA) & 0xFFFFFFFF


def _open(path: Path) -> BinaryIO:
    try:
        f = open(path, "rb")
    except OSError as exc:
        raise InputError(f"{path}: cannot open ({exc.strerror or exc})") from None
    if f.read(2) == GZIP_MAGIC:
        f.close()
        return gzip_module.open(path, "rb")  # type: ignore[return-value]
    f.seek(0)
    return f


_CHUNK = 1 << 24  # [bytes] read step: a damaged length header never makes us allocate more than the file holds


def _read_exact(f: BinaryIO, n: int, path: Path, index: int) -> bytes:
    """Up to ``n`` bytes (fewer at the end of the file), read in chunks of at most :data:`_CHUNK`."""
    parts: list[bytes] = []
    got = 0
    try:
        while got < n:
            part = f.read(min(_CHUNK, n - got))
            if not part:
                break
            parts.append(part)
            got += len(part)
    except (EOFError, OSError, zlib.error) as exc:  # corrupt or truncated gzip stream
        raise InputError(f"{path}: record {index}: corrupt gzip stream ({exc})") from None
    return parts[0] if len(parts) == 1 else b"".join(parts)


def iter_tfrecord(path: str | Path) -> Iterator[bytes]:
    """Yield the data of every record of a TFRecord file (plain or gzip), checking both CRCs."""
    path = Path(path)
    with _open(path) as f:
        index = 0
        while True:
            header = _read_exact(f, _HEADER, path, index)
            if not header:
                if index == 0:
                    raise InputError(f"{path}: empty file (not a TFRecord file)")
                return
            if len(header) < _HEADER:
                what = "not a TFRecord file" if index == 0 else "truncated record"
                raise InputError(f"{path}: record {index}: {what} "
                                 f"(header has {len(header)} of {_HEADER} bytes)")
            length_bytes, length_crc = header[:8], struct.unpack("<I", header[8:])[0]
            if masked_crc32c(length_bytes) != length_crc:
                what = "not a TFRecord file (length CRC mismatch)" if index == 0 else "length CRC mismatch"
                raise InputError(f"{path}: record {index}: {what}")
            (length,) = struct.unpack("<Q", length_bytes)
            body = _read_exact(f, length + _FOOTER, path, index)
            if len(body) < length + _FOOTER:
                raise InputError(f"{path}: record {index}: truncated record "
                                 f"(expected {length + _FOOTER} bytes after the header, got {len(body)})")
            data = body[:length]
            if masked_crc32c(data) != struct.unpack("<I", body[length:])[0]:
                raise InputError(f"{path}: record {index}: data CRC mismatch")
            yield data
            index += 1


def read_tfrecord(path: str | Path) -> list[bytes]:
    """All records of a TFRecord file."""
    return list(iter_tfrecord(path))


def encode_record(data: bytes) -> bytes:
    """One framed record."""
    length = struct.pack("<Q", len(data))
    return (length + struct.pack("<I", masked_crc32c(length)) + data
            + struct.pack("<I", masked_crc32c(data)))


def write_tfrecord(path: str | Path, records: Iterable[bytes], gzip: bool = False) -> Path:
    """Write ``records`` to a TFRecord file (gzip-compressed when ``gzip``); returns the path."""
    path = Path(path)
    f: BinaryIO
    if gzip:
        f = gzip_module.GzipFile(path, "wb", mtime=0)  # type: ignore[assignment]
    else:
        f = open(path, "wb")
    with f:
        for data in records:
            f.write(encode_record(bytes(data)))
    return path
