"""Streaming decoder: resync, counters, bounded buffer, arrival bookkeeping."""

import random

import pytest

from protocol.framing import encode_frame
from protocol.stream import StreamDecoder, max_encoded_len


def frames(n, start_seq=0, size=40):
    return [encode_frame(0x10, start_seq + i, bytes([i % 251 + 1]) * size) for i in range(n)]


def feed_all(dec, data, chunk=None):
    out = []
    if chunk is None:
        return dec.feed(data)
    for i in range(0, len(data), chunk):
        out += dec.feed(data[i:i + chunk])
    return out


@pytest.mark.parametrize("chunk", [None, 1, 7, 64])
def test_clean_stream_any_chunking(chunk):
    wire = b"\x00" + b"".join(frames(20))
    dec = StreamDecoder()
    got = feed_all(dec, wire, chunk)
    assert [r.frame.seq for r in got] == list(range(20))
    assert dec.stats.frames_ok == 20 and dec.stats.bytes_discarded == 0 and dec.stats.seq_gaps == 0


def test_partial_first_frame_after_open_is_discarded_and_counted():
    fs = frames(3)
    wire = fs[0][10:] + fs[1] + fs[2]
    dec = StreamDecoder()
    got = dec.feed(wire)
    assert [r.frame.seq for r in got] == [1, 2]
    assert dec.stats.bytes_discarded == len(fs[0]) - 10 - 1
    assert dec.stats.crc_errors == dec.stats.decode_errors == 0


def test_without_leading_delimiter_the_first_frame_is_treated_as_partial():
    dec = StreamDecoder()
    assert [r.frame.seq for r in dec.feed(b"".join(frames(2)))] == [1]
    assert [r.frame.seq for r in StreamDecoder(synced=True).feed(b"".join(frames(2)))] == [0, 1]


def test_bit_flip_costs_exactly_one_frame_and_is_counted_as_crc():
    fs = frames(5)
    bad = bytearray(fs[2])
    bad[20] ^= 0x04
    assert 0 not in bad[:-1]  # the flip must not forge a delimiter for this test's point
    dec = StreamDecoder(synced=True)
    got = dec.feed(b"".join(fs[:2]) + bytes(bad) + b"".join(fs[3:]))
    assert [r.frame.seq for r in got] == [0, 1, 3, 4]
    assert dec.stats.crc_errors == 1 and dec.stats.seq_gaps == 1 and dec.stats.frames_missing == 1
    assert dec.stats.bytes_discarded == len(fs[2])


def test_dropped_frames_show_as_sequence_gaps_across_wrap():
    wire = encode_frame(1, 65534, b"a") + encode_frame(1, 65535, b"b") + encode_frame(1, 2, b"c")
    dec = StreamDecoder(synced=True)
    assert [r.frame.seq for r in dec.feed(wire)] == [65534, 65535, 2]
    assert (dec.stats.seq_gaps, dec.stats.frames_missing) == (1, 2)


def test_runs_of_zeros_are_idle_fill():
    fs = frames(2)
    dec = StreamDecoder()
    got = dec.feed(b"\x00" * 50 + fs[0] + b"\x00" * 1000 + fs[1])
    assert len(got) == 2 and dec.stats.bytes_discarded == 0


@pytest.mark.parametrize("chunk", [None, 100, 4096])
def test_oversize_frame_is_dropped_and_buffer_stays_bounded(chunk):
    dec = StreamDecoder(max_payload=256)
    junk = bytes(random.Random(1).randrange(1, 256) for _ in range(10_000))
    good = encode_frame(2, 9, b"ok")
    got = feed_all(dec, b"\x00" + junk + b"\x00" + good, chunk)
    assert [r.frame.payload for r in got] == [b"ok"]
    assert dec.stats.oversize_frames == 1
    assert dec.stats.bytes_discarded == len(junk) + 1
    assert len(dec._buf) <= max_encoded_len(256)


def test_foreign_version_is_counted_and_remembered():
    from cobs import cobs
    import struct, zlib
    body = struct.pack("<BBHBH", 2, 0x02, 0, 0, 0)
    body += struct.pack("<I", zlib.crc32(body))
    dec = StreamDecoder(synced=True)
    assert dec.feed(cobs.encode(body) + b"\x00") == []
    assert dec.stats.decode_errors == 1 and dec.stats.version_seen == 2


def test_tail_tells_where_each_frame_ended_in_the_chunk():
    fs = frames(3, size=10)
    chunk = b"".join(fs)
    got = StreamDecoder(synced=True).feed(chunk)
    assert [r.tail for r in got] == [len(fs[1]) + len(fs[2]), len(fs[2]), 0]
    assert [r.wire_len for r in got] == [len(f) for f in fs]
