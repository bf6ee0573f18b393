"""The MCAP file around finished chunks (`chunks.py`): magic and header, the schemas and
channels (once, before any chunk), metadata records, the chunks as they come, and at the end
the summary (schemas, channels, statistics, chunk and metadata indexes, summary offsets) and
footer. Readers find every message through the chunk indexes as with any indexed MCAP file.
"""

from __future__ import annotations

import dataclasses
import struct
import zlib
from collections import defaultdict
from typing import BinaryIO

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Metadata,
    MetadataIndex,
    Statistics,
    SummaryOffset,
)
from mcap.writer import MCAP0_MAGIC

from drivee2e_data.logs.chunks import ChannelTable, FinishedChunk


class McapContainer:
    """Writes one MCAP file to `stream` (open, binary, at its start): `add_metadata`,
    `add_chunk` in any order, then `finish`."""

    def __init__(self, stream: BinaryIO, channels: ChannelTable, library: str) -> None:
        self.stream, self.table = stream, channels
        self.chunk_indexes: list[ChunkIndex] = []
        self.metadata_indexes: list[MetadataIndex] = []
        self.statistics = Statistics(
            message_count=0,
            schema_count=len(channels.schemas),
            channel_count=len(channels.channels),
            attachment_count=0,
            metadata_count=0,
            chunk_count=0,
            message_start_time=0,
            message_end_time=0,
            channel_message_counts=defaultdict(int),
        )
        stream.write(MCAP0_MAGIC)
        self._write(Header(profile="", library=library), *channels.schemas, *channels.channels)

    @classmethod
    def resumed(cls, stream: BinaryIO, channels: ChannelTable, state: dict) -> McapContainer:
        """A container that continues a file another one wrote up to `state` (its `state()`),
        with `stream` open at the end of what that one wrote: `finish` then writes the summary
        the first would have written."""
        container = cls.__new__(cls)
        container.stream, container.table = stream, channels
        container.chunk_indexes = [
            ChunkIndex(
                **{**index, "message_index_offsets": _int_keys(index["message_index_offsets"])}
            )
            for index in state["chunk_indexes"]
        ]
        container.metadata_indexes = [MetadataIndex(**index) for index in state["metadata_indexes"]]
        statistics = dict(state["statistics"])
        counts = defaultdict(int, _int_keys(statistics.pop("channel_message_counts")))
        container.statistics = Statistics(**statistics, channel_message_counts=counts)
        return container

    def state(self) -> dict:
        """What `resumed` needs to continue the file (JSON-ready): the indexes and statistics
        of what was written."""
        return {
            "chunk_indexes": [dataclasses.asdict(index) for index in self.chunk_indexes],
            "metadata_indexes": [dataclasses.asdict(index) for index in self.metadata_indexes],
            "statistics": {
                field.name: getattr(self.statistics, field.name)
                for field in dataclasses.fields(self.statistics)
            }
            | {"channel_message_counts": dict(self.statistics.channel_message_counts)},
        }

    def _write(self, *records: McapRecord) -> int:
        """Write records at the current position; returns how many bytes."""
        builder = RecordBuilder()
        for record in records:
            record.write(builder)
        data = builder.end()
        self.stream.write(data)
        return len(data)

    def add_metadata(self, name: str, values: dict[str, str]) -> None:
        offset = self.stream.tell()
        length = self._write(Metadata(name=name, metadata=values))
        self.metadata_indexes.append(MetadataIndex(offset=offset, length=length, name=name))
        self.statistics.metadata_count += 1

    def add_chunk(self, chunk: FinishedChunk) -> None:
        offset = self.stream.tell()
        self.stream.write(chunk.data)
        self.chunk_indexes.append(
            ChunkIndex(
                message_start_time=chunk.message_start_time,
                message_end_time=chunk.message_end_time,
                chunk_start_offset=offset,
                chunk_length=chunk.chunk_length,
                message_index_offsets={
                    channel: offset + position
                    for channel, position in chunk.message_index_offsets.items()
                },
                message_index_length=chunk.message_index_length,
                compression=chunk.compression,
                compressed_size=chunk.compressed_size,
                uncompressed_size=chunk.uncompressed_size,
            )
        )
        statistics = self.statistics
        if statistics.message_count == 0:
            statistics.message_start_time = chunk.message_start_time
        statistics.message_start_time = min(statistics.message_start_time, chunk.message_start_time)
        statistics.message_end_time = max(statistics.message_end_time, chunk.message_end_time)
        for channel, count in chunk.message_counts.items():
            statistics.channel_message_counts[channel] += count
            statistics.message_count += count
        statistics.chunk_count += 1

    def finish(self) -> None:
        """The data section's end, the summary, the footer and the closing magic."""
        self._write(DataEnd(data_section_crc=0))
        summary_start = self.stream.tell()
        builder, offsets = RecordBuilder(), []
        groups: list[tuple[Opcode, list[McapRecord]]] = [
            (Opcode.SCHEMA, list(self.table.schemas)),
            (Opcode.CHANNEL, list(self.table.channels)),
            (Opcode.STATISTICS, [self.statistics]),
            (Opcode.CHUNK_INDEX, list(self.chunk_indexes)),
            (Opcode.METADATA_INDEX, list(self.metadata_indexes)),
        ]
        for opcode, records in groups:
            group_start = builder.count
            for record in records:
                record.write(builder)
            offsets.append(
                SummaryOffset(
                    group_opcode=opcode,
                    group_start=summary_start + group_start,
                    group_length=builder.count - group_start,
                )
            )
        summary_offset_start = summary_start + builder.count
        for offset in offsets:
            offset.write(builder)
        summary = builder.end()
        footer_head = struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, summary_offset_start)
        crc = zlib.crc32(footer_head, zlib.crc32(summary))
        self.stream.write(summary)
        self._write(
            Footer(
                summary_start=summary_start,
                summary_offset_start=summary_offset_start,
                summary_crc=crc,
            )
        )
        self.stream.write(MCAP0_MAGIC)


def _int_keys(mapping: dict) -> dict[int, int]:
    """A channel-id map read back from JSON (its keys became strings), in its order."""
    return {int(key): value for key, value in mapping.items()}
