"""Reads a clip's log: metadata, one frame's messages by random access (only the chunks that
hold that frame are read and decompressed), the ego's states, and validation against the
contract. Needs only `mcap` and protobuf; never the simulator.
"""

from __future__ import annotations

import io
import json
import struct
from collections import Counter
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Chunk, Footer, Message, Metadata, MetadataIndex, SummaryOffset
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap_protobuf.decoder import DecoderFactory
from numpy.typing import NDArray
from zstandard import ZstdError

from drivee2e_data.errors import LogFormatError
from drivee2e_data.logs import topics
from drivee2e_data.sensors.ego_state import (
    FUTURE_STEPS,
    FUTURE_STRIDE_FRAMES,
    future_path,
)

RECORD_HEAD_SIZE = 9  # a record's opcode (1 byte) and length (8), as MCAP lays them out
FOOTER_RECORD_SIZE = RECORD_HEAD_SIZE + 20  # the footer: two offsets and a CRC
MAGIC_SIZE = 8  # the closing magic
# what reading a damaged or cut log raises, in the mcap library and below it
READ_ERRORS = (McapError, ValueError, EOFError, OSError, ZstdError, struct.error)
REQUIRED_METADATA = (
    topics.SCENARIO_METADATA,
    topics.RIG_METADATA,
    topics.COLLECTION_METADATA,
    topics.FRAMES_METADATA,
)


class LogReader:
    """One log, open for reading. Frames are numbered as in the scenario (`first_frame` on)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        try:
            self._file = open(self.path, "rb")
        except OSError as error:
            raise LogFormatError(f"{self.path}: cannot open ({error.strerror})") from None
        self._summary: Any = None
        try:
            self._reader = make_reader(self._file, decoder_factories=[DecoderFactory()])
            metadata = _metadata_through_offsets(self._file)
            if metadata is None:  # no summary offsets (another writer): the whole summary
                self._summary = self._whole_summary()
                metadata = {
                    record.name: dict(record.metadata) for record in self._reader.iter_metadata()
                }
        except READ_ERRORS as error:
            self._file.close()
            raise LogFormatError(f"{self.path}: not a complete MCAP log ({error})") from None
        except LogFormatError:
            self._file.close()
            raise
        missing = [name for name in REQUIRED_METADATA if name not in metadata]
        if missing:
            self._file.close()
            raise LogFormatError(f"{self.path}: metadata record {missing[0]!r} is missing")
        self.metadata = metadata
        frames = metadata[topics.FRAMES_METADATA]
        self.first_frame = int(frames["first_frame"])
        # sensors at every n-th frame (`collect --sensor-hz`); logs before 2026-11-24: every
        self.sensor_every = int(frames.get("sensor_every", "1"))
        self.t_ns: NDArray[np.int64] = np.array(json.loads(frames["t_ns"]), np.int64)
        self.scenario_meta: dict[str, Any] = json.loads(metadata[topics.SCENARIO_METADATA]["meta"])
        self.rig: dict[str, Any] = json.loads(metadata[topics.RIG_METADATA]["rig"])
        self.collection: dict[str, str] = metadata[topics.COLLECTION_METADATA]
        self._chunks_at: dict[int, list[Any]] | None = None  # built by frame_raw on first use

    @property
    def summary(self) -> Any:
        """The log's summary section (schemas, channels, statistics, chunk indexes), read on
        first use: opening a log reads only its metadata."""
        if self._summary is None:
            try:
                self._summary = self._whole_summary()
            except READ_ERRORS as error:
                raise LogFormatError(f"{self.path}: not a complete MCAP log ({error})") from None
        return self._summary

    def _whole_summary(self) -> Any:
        summary = self._reader.get_summary()
        if summary is None:
            raise LogFormatError(f"{self.path}: the log has no summary section (incomplete)")
        return summary

    @property
    def scenario_id(self) -> str:
        return str(self.scenario_meta["scenario_id"])

    @property
    def num_frames(self) -> int:
        return len(self.t_ns)

    @property
    def frames(self) -> range:
        """Every frame of the log: the ego's state, IMU, GNSS and the lights are at each."""
        return range(self.first_frame, self.first_frame + self.num_frames)

    @property
    def sensor_frames(self) -> range:
        """The frames with sensor data and boxes: all at 10 Hz, every fifth at 2 Hz."""
        return range(self.first_frame, self.first_frame + self.num_frames, self.sensor_every)

    @property
    def cameras(self) -> tuple[str, ...]:
        return tuple(self.rig["cameras"])

    @property
    def lidar_to_ego(self) -> NDArray[np.float64]:
        """(4, 4) the LiDAR's pose in the ego frame, from the logged rig."""
        (lidar,) = self.rig["lidar"].values()
        return np.array(lidar["sensor_to_ego"], np.float64)

    @property
    def camera_label_kinds(self) -> tuple[str, ...]:
        """The dense label kinds logged per camera (`collect --camera-labels`); () for none."""
        return self.camera_label_info.get("kinds", ())

    @property
    def camera_label_info(self) -> dict[str, Any]:
        """The labels' record: kinds, scale, width, height, depth unit, the semantic class
        names and the instance values' track ids (index k is instance value k + 1)."""
        record = self.metadata.get(topics.CAMERA_LABELS_METADATA)
        if not record:
            return {}
        return {
            "kinds": tuple(record["kinds"].split(",")),
            "scale": int(record["scale"]),
            "size": (int(record["width"]), int(record["height"])),
            "depth_unit": record["depth_unit"],
            "semantic_classes": tuple(json.loads(record["semantic_classes"])),
            "instance_track_ids": tuple(json.loads(record["instance_track_ids"])),
        }

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> LogReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def time_of(self, frame: int) -> int:
        if frame not in self.frames:
            raise IndexError(
                f"{self.path}: frame {frame} is not in the log (frames {self.frames.start}-"
                f"{self.frames.stop - 1})"
            )
        return int(self.t_ns[frame - self.first_frame])

    def frame(self, frame: int, topic_names: Iterable[str] | None = None) -> dict[str, Any]:
        """Decoded messages of one frame, by topic (all topics unless `topic_names` is given)."""
        t = self.time_of(frame)
        wanted = None if topic_names is None else list(topic_names)
        try:
            return {
                channel.topic: message
                for _, channel, _, message in self._reader.iter_decoded_messages(
                    topics=wanted, starting_at=t, ending_at=t
                )
            }
        except (McapError, EOFError, ValueError, ZstdError) as error:
            raise LogFormatError(
                f"{self.path}: unreadable chunk at frame {frame} ({error})"
            ) from None

    def decoded_messages(self, topic_names: Iterable[str]) -> Iterator[tuple[Any, Any, Any, Any]]:
        """Every message of these topics in log-time order: (schema, channel, message, decoded).
        Reads only the chunks that hold these topics."""
        try:
            yield from self._reader.iter_decoded_messages(topics=list(topic_names))
        except (McapError, ZstdError) as error:  # a damaged chunk fails to inflate
            raise LogFormatError(f"{self.path}: unreadable chunk ({error})") from None

    def frame_raw(self, frame: int, topic_names: Iterable[str]) -> dict[str, bytes]:
        """Undecoded message bytes of one frame, by topic: the training loader's fast path.

        Logs written a frame to a chunk (see `writer.py`) are read straight from the chunk
        index: only the chunks of that frame holding these topics are read, without scanning
        the index per call. Older logs, whose chunks span frames, take the general path."""
        t = self.time_of(frame)
        wanted = set(topic_names)
        if self._chunks_at is None:
            self._chunks_at = _chunks_by_frame(self.summary)
        try:
            if t not in self._chunks_at:
                return {
                    channel.topic: message.data
                    for _, channel, message in self._reader.iter_messages(
                        topics=list(wanted), start_time=t, end_time=t + 1
                    )
                }
            found = {}
            for chunk_index in self._chunks_at[t]:
                topics_here = {
                    self.summary.channels[c].topic for c in chunk_index.message_index_offsets
                }
                if not topics_here & wanted:
                    continue
                self._file.seek(chunk_index.chunk_start_offset + 1 + 8)
                chunk = Chunk.read(ReadDataStream(self._file))
                for record in breakup_chunk(chunk, validate_crc=False):
                    if isinstance(record, Message) and record.log_time == t:
                        topic = self.summary.channels[record.channel_id].topic
                        if topic in wanted:
                            found[topic] = record.data
            return found
        except (McapError, EOFError, ValueError, ZstdError) as error:
            raise LogFormatError(
                f"{self.path}: unreadable chunk at frame {frame} ({error})"
            ) from None

    def ego_states(self) -> list[Any]:
        """Every frame's `/ego/state`, in frame order."""
        return [m for _, _, _, m in self._reader.iter_decoded_messages(topics=[topics.EGO_STATE])]

    def future_path(self, frame: int) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """The ego's 2 Hz future over 3 s in its frame at `frame`, `(6, 2)`, and which steps the
        log has; read from the `/ego/state` of those frames only."""
        self.time_of(frame)  # a frame outside the log is an IndexError naming the log
        steps = [frame + FUTURE_STRIDE_FRAMES * k for k in range(FUTURE_STEPS + 1)]
        steps = [step for step in steps if step in self.frames]
        # positions by frame offset from `frame`; only the steps are read, NaN between them
        x, y, yaw = np.full((3, steps[-1] - frame + 1), np.nan)
        for step in steps:
            state = self.frame(step, [topics.EGO_STATE])[topics.EGO_STATE]
            x[step - frame], y[step - frame], yaw[step - frame] = state.x, state.y, state.yaw
        return future_path(x, y, yaw, 0)

    def validate(self) -> None:
        """Every state topic once at every frame, every sensor topic once at every sensor frame
        (and never between), `/map` once at the first, and the summary's counts agreeing;
        raises `LogFormatError` naming the first gap."""
        exposure = {topics.exposure_topic(c) for c in self.cameras}
        recorded = {channel.topic for channel in self.summary.channels.values()}
        expected = set(topics.per_frame_topics(self.cameras, bool(exposure & recorded)))
        expected |= {
            topics.camera_label_topic(camera, kind)
            for camera in self.cameras
            for kind in self.camera_label_kinds
        }
        times = {int(t): self.first_frame + i for i, t in enumerate(self.t_ns)}
        seen: Counter[tuple[str, int]] = Counter()
        try:
            for _, channel, message in self._reader.iter_messages():
                if message.log_time not in times:
                    raise LogFormatError(
                        f"{self.path}: topic {channel.topic} has a message at t_ns "
                        f"{message.log_time}, which is no frame of the log"
                    )
                seen[(channel.topic, message.log_time)] += 1
        except (McapError, ZstdError) as error:  # a damaged chunk fails to inflate
            raise LogFormatError(f"{self.path}: unreadable chunk ({error})") from None
        first = int(self.t_ns[0])
        sensor_frames = set(self.sensor_frames)
        for t, frame in times.items():
            for topic in sorted(expected | {topics.MAP}):
                count = seen[(topic, t)]
                wanted = int(topic in topics.STATE_TOPICS or frame in sensor_frames)
                if topic == topics.MAP:
                    wanted = 1 if t == first else 0
                if count != wanted:
                    raise LogFormatError(
                        f"{self.path}: topic {topic} has {count} messages at frame {frame} "
                        f"(t_ns {t}), expected {wanted}"
                    )
        unexpected = {topic for topic, _ in seen} - expected - {topics.MAP}
        if unexpected:
            raise LogFormatError(f"{self.path}: unexpected topic {sorted(unexpected)[0]}")
        counts = self.summary.statistics.channel_message_counts if self.summary.statistics else {}
        for channel_id, channel in self.summary.channels.items():
            wanted = len(self.sensor_frames)
            if channel.topic in topics.STATE_TOPICS:
                wanted = self.num_frames
            elif channel.topic == topics.MAP:
                wanted = 1
            if counts.get(channel_id) != wanted:
                raise LogFormatError(
                    f"{self.path}: the summary counts {counts.get(channel_id)} messages on "
                    f"{channel.topic}, expected {wanted}"
                )


def _metadata_through_offsets(stream: BinaryIO) -> dict[str, dict[str, str]] | None:
    """The log's metadata records by name, found through its summary offsets: the footer, the
    offsets, the metadata-index group, then each record (mcap's record types parse each one).
    None where the log has no summary offsets. Parsing the whole summary instead (its chunk
    indexes are most of it) took 9 ms a 2 Hz clip on 2 cores against 0.3 here, and every
    Dataset and feature cache opens each of its logs (400 clips: 4 s against 0.1)."""
    stream.seek(-(FOOTER_RECORD_SIZE + MAGIC_SIZE), io.SEEK_END)
    footer = next(StreamReader(stream, skip_magic=True).records)  # checks the closing magic
    if not isinstance(footer, Footer):
        raise McapError(f"expected the footer at the end, found {type(footer).__name__}")
    if footer.summary_start == 0:
        raise LogFormatError(f"{stream.name}: the log has no summary section (incomplete)")
    if footer.summary_offset_start == 0:
        return None
    stream.seek(footer.summary_offset_start)
    groups = {
        offset.group_opcode: offset
        for offset in _group_records(stream.read(), SummaryOffset, stop_at=Opcode.FOOTER)
    }
    if Opcode.METADATA_INDEX not in groups:
        return {}
    group = groups[Opcode.METADATA_INDEX]
    stream.seek(group.group_start)
    metadata = {}
    for index in _group_records(stream.read(group.group_length), MetadataIndex):
        stream.seek(index.offset)
        record = next(StreamReader(stream, skip_magic=True).records)
        if not isinstance(record, Metadata):
            raise McapError(f"expected a metadata record at {index.offset}")
        metadata[record.name] = dict(record.metadata)
    return metadata


def _group_records(data: bytes, kind: Any, stop_at: int | None = None) -> list[Any]:
    """The records of one type in `data` (records back to back: opcode, length, body), up to
    the first with opcode `stop_at`."""
    records, position = [], 0
    while position < len(data):
        opcode, length = struct.unpack_from("<BQ", data, position)
        if opcode == stop_at:
            break
        body = data[position + RECORD_HEAD_SIZE : position + RECORD_HEAD_SIZE + length]
        records.append(kind.read(ReadDataStream(io.BytesIO(body))))
        position += RECORD_HEAD_SIZE + length
    return records


def _chunks_by_frame(summary: Any) -> dict[int, list[Any]]:
    """Chunk indexes by the one frame time they hold; empty when any chunk spans frames."""
    by_time: dict[int, list[Any]] = {}
    for chunk_index in summary.chunk_indexes:
        if chunk_index.message_start_time != chunk_index.message_end_time:
            return {}
        by_time.setdefault(chunk_index.message_start_time, []).append(chunk_index)
    return by_time


def validate(path: Path) -> int:
    """Validate the log at `path`; returns its number of frames."""
    with LogReader(path) as log:
        log.validate()
        return log.num_frames
