"""TFRecord framing: round trips (plain and gzip) and one-line errors naming file and record."""

from __future__ import annotations

import gzip

import pytest
from coster_sumo.converters.tfrecord import encode_record, iter_tfrecord, masked_crc32c, read_tfrecord, write_tfrecord

from coster_sumo.errors import InputError

RECORDS = [b"", b"a", b"hello world" * 100, bytes(range(256)) * 3]


def test_masked_crc_known_value():
    # TensorFlow's framing of an empty record: length 0, then its masked CRC
    assert encode_record(b"")[:12] == bytes(8) + masked_crc32c(bytes(8)).to_bytes(4, "little")
    assert masked_crc32c(b"") == 0xA282EAD8  # crc32c("") = 0, masked


@pytest.mark.parametrize("compress", [False, True])
def test_round_trip_many_records(tmp_path, compress):
    path = write_tfrecord(tmp_path / "x.tfrecord", RECORDS, gzip=compress)
    assert read_tfrecord(path) == RECORDS
    assert (path.read_bytes()[:2] == b"\x1f\x8b") == compress


def test_gzip_detected_by_content_not_name(tmp_path):
    plain = tmp_path / "a.tfrecord"
    write_tfrecord(plain, RECORDS)
    hidden = tmp_path / "b.tfrecord"  # gzip without a .gz suffix
    hidden.write_bytes(gzip.compress(plain.read_bytes()))
    assert read_tfrecord(hidden) == RECORDS


def _error(path) -> str:
    with pytest.raises(InputError) as info:
        list(iter_tfrecord(path))
    msg = str(info.value)
    assert "\n" not in msg and str(path) in msg
    return msg


def test_truncated_record(tmp_path):
    path = write_tfrecord(tmp_path / "t.tfrecord", RECORDS)
    data = path.read_bytes()
    path.write_bytes(data[:-3])
    assert "record 3: truncated record" in _error(path)
    path.write_bytes(data[:len(encode_record(RECORDS[0])) + 5])  # cut inside record 1's header
    assert "record 1: truncated record" in _error(path)


def test_truncated_gzip(tmp_path):
    path = write_tfrecord(tmp_path / "t.tfrecord.gz", RECORDS, gzip=True)
    path.write_bytes(path.read_bytes()[:-12])
    assert "record" in _error(path)


def test_flipped_data_byte_is_data_crc_mismatch(tmp_path):
    path = write_tfrecord(tmp_path / "f.tfrecord", RECORDS)
    data = bytearray(path.read_bytes())
    start = len(encode_record(RECORDS[0])) + len(encode_record(RECORDS[1])) + 12  # record 2's data
    data[start + 5] ^= 0x01
    path.write_bytes(bytes(data))
    assert "record 2: data CRC mismatch" in _error(path)


def test_flipped_length_byte_is_length_crc_mismatch(tmp_path):
    path = write_tfrecord(tmp_path / "l.tfrecord", RECORDS)
    data = bytearray(path.read_bytes())
    data[len(encode_record(RECORDS[0]))] ^= 0x40  # record 1's length
    path.write_bytes(bytes(data))
    assert "record 1: length CRC mismatch" in _error(path)


def test_not_a_tfrecord(tmp_path):
    path = tmp_path / "notes.txt"
    path.write_text("this is just some text, certainly not a TFRecord file\n")
    assert "record 0: not a TFRecord file" in _error(path)
    path.write_bytes(b"abc")
    assert "not a TFRecord file" in _error(path)


def test_empty_file(tmp_path):
    path = tmp_path / "empty.tfrecord"
    path.write_bytes(b"")
    assert "empty file" in _error(path)


def test_missing_file(tmp_path):
    assert "cannot open" in _error(tmp_path / "nope.tfrecord")
