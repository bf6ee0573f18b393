"""MCAP chunks made apart from the file they go into. A frame's messages become finished chunk
records (compressed, each followed by its message indexes) that any process can make and a log
writer appends as they are; what the summary needs of a chunk is read back from its bytes.

So a worker that collects a segment of a clip does all the compression, and writing the clip's
log from its segments is a copy (`collect/segments.py`). Channel and schema ids are fixed up
front from the topics a log can carry (`ChannelTable`), so a chunk's bytes do not depend on
which frames were written before it.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from functools import cached_property

import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, MessageIndex, Schema
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap_protobuf.schema import build_file_descriptor_set

from drivee2e_data.errors import LogFormatError

COMPRESSION = "zstd"
# zstd's level 1: it packs a frame's LiDAR chunk (1.9 MB) to 0.438 of its size in 3.3 ms here
# and its images (JPEG) to 0.89 in 0.7 ms, where the default level 3 took 5.6 and 1.2 ms for
# 0.427 and 0.874: a log 2% larger for 1% more frames a second on 2 cores (docs/benchmarks.md,
# "twelfth session")
ZSTD_LEVEL = 1

# a message record: opcode, length, channel id, sequence, log time, publish time (then data)
_MESSAGE = struct.Struct("<BQHIQQ")
_MESSAGE_FIELDS = _MESSAGE.size - 9  # what the length counts before the data
# a chunk record's fixed start: opcode, length, start and end time, uncompressed size and CRC
_CHUNK_HEAD = struct.Struct("<BQQQQI")
_RECORD_HEAD = struct.Struct("<BQ")


@dataclass(frozen=True)
class ChannelTable:
    """A log's schemas and channels, numbered from 1 in the order given: `topics` is (topic,
    protobuf message class) for every topic the log may carry."""

    schemas: tuple[Schema, ...]
    channels: tuple[Channel, ...]

    @staticmethod
    def of(topics: list[tuple[str, type]]) -> ChannelTable:
        schema_ids: dict[str, int] = {}
        schemas, channels = [], []
        for topic, message_class in topics:
            name = message_class.DESCRIPTOR.full_name
            if name not in schema_ids:
                schema_ids[name] = len(schemas) + 1
                data = build_file_descriptor_set(message_class).SerializeToString()
                schemas.append(
                    Schema(
                        id=schema_ids[name], name=name, encoding=SchemaEncoding.Protobuf, data=data
                    )
                )
            channels.append(
                Channel(
                    id=len(channels) + 1,
                    topic=topic,
                    message_encoding=MessageEncoding.Protobuf,
                    schema_id=schema_ids[name],
                    metadata={},
                )
            )
        return ChannelTable(tuple(schemas), tuple(channels))

    @cached_property
    def _ids(self) -> dict[str, int]:
        return {channel.topic: channel.id for channel in self.channels}

    def channel_id(self, topic: str) -> int:
        try:
            return self._ids[topic]
        except KeyError:
            raise KeyError(f"topic {topic} has no channel in this log") from None


@dataclass(frozen=True)
class FinishedChunk:
    """A chunk record followed by its message index records (`data`, as they go into the
    file), and what the summary's chunk index and statistics say of them."""

    data: bytes
    chunk_length: int  # bytes of the chunk record; its message indexes follow
    message_start_time: int
    message_end_time: int
    compression: str
    compressed_size: int
    uncompressed_size: int
    message_index_offsets: dict[int, int]  # channel id -> its index's offset in `data`
    message_counts: dict[int, int]  # channel id -> messages in the chunk

    @property
    def message_index_length(self) -> int:
        return len(self.data) - self.chunk_length


_compressor = zstandard.ZstdCompressor(level=ZSTD_LEVEL)


def finish_chunk(messages: list[tuple[int, bytes]], t_ns: int) -> FinishedChunk:
    """One chunk of `messages` ((channel id, bytes), all stamped `t_ns` as log and publish
    time), compressed, with one message index per channel in the order channels first
    appear."""
    parts, indexes, offset = [], {}, 0
    for channel_id, data in messages:
        indexes.setdefault(channel_id, []).append((t_ns, offset))
        parts.append(
            _MESSAGE.pack(Opcode.MESSAGE, _MESSAGE_FIELDS + len(data), channel_id, 0, t_ns, t_ns)
        )
        parts.append(data)
        offset += _MESSAGE.size + len(data)
    records = b"".join(parts)
    compressed = _compressor.compress(records)
    builder = RecordBuilder()
    Chunk(
        compression=COMPRESSION,
        data=compressed,
        message_end_time=t_ns,
        message_start_time=t_ns,
        uncompressed_crc=zlib.crc32(records),
        uncompressed_size=len(records),
    ).write(builder)
    chunk_length = builder.count
    index_offsets = {}
    for channel_id, entries in indexes.items():
        index_offsets[channel_id] = builder.count
        MessageIndex(channel_id, entries).write(builder)
    return FinishedChunk(
        builder.end(),
        chunk_length,
        t_ns,
        t_ns,
        COMPRESSION,
        len(compressed),
        len(records),
        index_offsets,
        {channel_id: len(entries) for channel_id, entries in indexes.items()},
    )


def read_chunk(data: bytes, where: str) -> FinishedChunk:
    """A `FinishedChunk` from its bytes (a chunk record then its message indexes), reading
    only the records' heads, never inflating; `where` names the bytes' origin in errors."""
    try:
        opcode, length, start, end, uncompressed, _ = _CHUNK_HEAD.unpack_from(data)
        if opcode != Opcode.CHUNK:
            raise LogFormatError(f"{where}: expected a chunk record, found opcode {opcode}")
        position = _CHUNK_HEAD.size
        (name_length,) = struct.unpack_from("<I", data, position)
        compression = data[position + 4 : position + 4 + name_length].decode()
        (compressed,) = struct.unpack_from("<Q", data, position + 4 + name_length)
        chunk_length = 9 + length
        offsets, counts = {}, {}
        position = chunk_length
        while position < len(data):
            opcode, length = _RECORD_HEAD.unpack_from(data, position)
            if opcode != Opcode.MESSAGE_INDEX:
                raise LogFormatError(f"{where}: expected a message index, found opcode {opcode}")
            channel_id, entries_bytes = struct.unpack_from("<HI", data, position + 9)
            offsets[channel_id], counts[channel_id] = position, entries_bytes // 16
            position += 9 + length
    except (struct.error, UnicodeDecodeError) as error:
        raise LogFormatError(f"{where}: damaged chunk ({error})") from None
    if position != len(data):
        raise LogFormatError(f"{where}: damaged chunk (its records overrun its bytes)")
    return FinishedChunk(
        data, chunk_length, start, end, compression, compressed, uncompressed, offsets, counts
    )
