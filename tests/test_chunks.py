"""Finished MCAP chunks (`logs/chunks.py`) and the file around them (`logs/container.py`):
known messages in, the same messages out through the plain `mcap` reader."""

from __future__ import annotations

import io

import pytest
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk

from drivee2e_data.errors import LogFormatError
from drivee2e_data.logs.chunks import ChannelTable, finish_chunk, read_chunk
from drivee2e_data.logs.container import McapContainer

T = 1_700_000_000_000_000_000


def table() -> ChannelTable:
    return ChannelTable.of([("/a", CompressedImage), ("/b", PointCloud), ("/c", CompressedImage)])


def test_channels_are_numbered_in_order_and_share_a_schema_per_type():
    channels = table()
    assert [c.id for c in channels.channels] == [1, 2, 3]
    assert [s.name for s in channels.schemas] == ["foxglove.CompressedImage", "foxglove.PointCloud"]
    assert [c.schema_id for c in channels.channels] == [1, 2, 1]
    assert channels.channel_id("/c") == 3
    with pytest.raises(KeyError, match="/d"):
        channels.channel_id("/d")


def test_a_finished_chunk_holds_its_messages_and_reads_back_from_its_bytes():
    messages = [(1, b"first"), (2, b"x" * 1000), (1, b"third")]
    chunk = finish_chunk(messages, T)
    assert chunk.message_counts == {1: 2, 2: 1}
    assert (chunk.message_start_time, chunk.message_end_time) == (T, T)
    # the chunk record inflates to the three messages, in order, each stamped T
    record = Chunk.read(ReadDataStream(io.BytesIO(chunk.data[9 : chunk.chunk_length])))
    inside = [r for r in breakup_chunk(record, validate_crc=True) if isinstance(r, Message)]
    assert [(m.channel_id, m.data, m.log_time, m.publish_time) for m in inside] == [
        (c, d, T, T) for c, d in messages
    ]
    assert record.uncompressed_size == chunk.uncompressed_size
    assert len(record.data) == chunk.compressed_size < chunk.uncompressed_size
    # what the summary needs is read back from the bytes alone
    assert read_chunk(chunk.data, "here") == chunk


def test_a_damaged_chunk_is_an_error_naming_where_it_came_from():
    chunk = finish_chunk([(1, b"abc")], T)
    with pytest.raises(LogFormatError, match=r"seg\.segment: frame 3"):
        read_chunk(chunk.data[:-5], "seg.segment: frame 3")
    with pytest.raises(LogFormatError, match="expected a chunk record"):
        read_chunk(b"\x01" + chunk.data[1:], "seg.segment: frame 3")


def test_a_container_of_finished_chunks_reads_with_plain_mcap():
    stream = io.BytesIO()
    container = McapContainer(stream, table(), "test")
    container.add_metadata("first", {"k": "v"})
    for k in range(3):
        container.add_chunk(finish_chunk([(1, b"img%d" % k), (3, b"other")], T + k))
        container.add_chunk(finish_chunk([(2, b"cloud%d" % k)], T + k))
    container.add_metadata("last", {"n": "3"})
    container.finish()
    stream.seek(0)
    reader = make_reader(stream)
    summary = reader.get_summary()
    assert summary.statistics.message_count == 9
    assert dict(summary.statistics.channel_message_counts) == {1: 3, 2: 3, 3: 3}
    assert summary.statistics.chunk_count == len(summary.chunk_indexes) == 6
    assert (summary.statistics.message_start_time, summary.statistics.message_end_time) == (
        T,
        T + 2,
    )
    assert {m.name: m.metadata for m in reader.iter_metadata()} == {
        "first": {"k": "v"},
        "last": {"n": "3"},
    }
    # by topic through the chunk and message indexes: only the /b cloud chunks
    clouds = [(m.log_time, m.data) for _, _, m in reader.iter_messages(topics=["/b"])]
    assert clouds == [(T + k, b"cloud%d" % k) for k in range(3)]
    at_one = {
        c.topic: m.data for _, c, m in reader.iter_messages(start_time=T + 1, ending_before=T + 2)
    }
    assert at_one == {"/a": b"img1", "/b": b"cloud1", "/c": b"other"}
