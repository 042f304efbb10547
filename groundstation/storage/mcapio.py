"""MCAP reading and writing: the one module that imports the ``mcap`` library.

Writing: :class:`McapFileWriter` wraps ``mcap.writer.Writer`` with lazy channel registration,
an explicit flush (closes the chunk in progress and flushes the file, so a killed process loses
at most what arrived since) and an idempotent :meth:`~McapFileWriter.finish`. Files are created
exclusively: an existing file is never overwritten. They are written through :class:`ExactFile`,
unbuffered and never silently short (a full disk makes ``os.write`` write less than asked), so
the size after a successful flush is a known-good chunk boundary: :meth:`McapFileWriter.abandon`
cuts a file whose write failed back to it, leaving an unfinished but clean file. Asked to
(``keep_unsettled``), it keeps the uncompressed chunks since the caller last called
:meth:`~McapFileWriter.settle` and gives their messages back (:meth:`~McapFileWriter.unsettled`):
what the session recorder moves to its backlog when a write fails. Records can be encoded
straight into the chunk in progress (:meth:`~McapFileWriter.add_typed`).

Reading: :func:`iter_messages` reads linearly (streaming), which works the same for finished
files and for files whose writer died: it returns every message up to the last complete chunk
and stops quietly at the torn tail. :func:`read_head_metadata` reads only the metadata before
the first chunk (the session's part number, for following a session's parts).
:func:`read_summary` uses the seeking reader's summary when the file was finished.
"""

from __future__ import annotations

import collections
import contextlib
import errno
import logging
import os
import struct
import zlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Protocol

import lz4.frame  # type: ignore[import-untyped]
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.reader import make_reader
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Message,
    MessageIndex,
    Metadata,
    Schema,
)
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, IndexType, Writer

from groundstation import jsonio

log = logging.getLogger("groundstation.storage")

_COMPRESSION = {
    "zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE
}
RAW_TOPIC = "/ubx/raw"


@dataclass(frozen=True, slots=True)
class ChannelSpec:
    """What a channel carries: topic, message encoding and (optionally) its schema."""

    topic: str
    message_encoding: str
    schema_name: str = ""
    schema_encoding: str = ""
    schema_data: bytes = b""


def json_channel(topic: str, schema: dict[str, Any]) -> ChannelSpec:
    """A JSON channel with a JSON Schema (its ``title`` names the schema)."""
    return ChannelSpec(
        topic, "json", str(schema.get("title", topic)), "jsonschema",
        jsonio.dumps(schema),
    )


class WritableFile(Protocol):
    """What the recorder writes through (:class:`ExactFile`, or a test's faulty wrapper)."""

    path: Path

    def write(self, data: bytes | bytearray | memoryview, /) -> int: ...

    def tell(self) -> int: ...

    def flush(self) -> None: ...

    def truncate(self, size: int, /) -> None: ...

    def close(self) -> None: ...


class ExactFile:
    """A new file (created exclusively), written unbuffered: every byte, or an ``OSError``.

    ``os.write`` writes less than asked when the disk fills up; :meth:`write` goes on until
    all is written or the system refuses, so a short write is never mistaken for success. The
    position is counted here and stays right after a failure.

    Raises:
        FileExistsError: if ``path`` exists.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o666)
        self._pos = 0
        self.closed = False

    def _write_some(self, data: memoryview) -> int:
        """One ``write(2)``; the fault hook tests override."""
        return os.write(self._fd, data)

    def write(self, data: bytes | bytearray | memoryview, /) -> int:
        view = memoryview(data).cast("B")
        total = len(view)
        while view:
            n = self._write_some(view)
            if n <= 0:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self.path))
            self._pos += n
            view = view[n:]
        return total

    def tell(self) -> int:
        return self._pos

    def flush(self) -> None:
        """Nothing is buffered here (no fsync either)."""

    def truncate(self, size: int, /) -> None:
        """Cut the file to ``size`` bytes and continue writing there."""
        os.ftruncate(self._fd, size)
        os.lseek(self._fd, size, os.SEEK_SET)
        self._pos = size

    def fileno(self) -> int:
        return self._fd

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            os.close(self._fd)


class _RawRecords:
    """Summary records already serialised (what :class:`PackedChunkIndexes` yields)."""

    __slots__ = ("data",)

    def __init__(self, data: bytes) -> None:
        self.data = data

    def write(self, builder: RecordBuilder) -> None:
        builder.write(self.data)


class PackedChunkIndexes:
    """Stands in for the mcap writer's list of ``ChunkIndex`` records, keeping each one as the
    bytes of its summary record: about 150 bytes a chunk instead of about 650 for the object
    and its dict of message-index offsets. The writer only appends to the list and iterates it
    once, in :meth:`mcap.writer.Writer.finish`, to write the summary; the bytes written are the
    same (checked in the tests)."""

    def __init__(self) -> None:
        self._data = bytearray()
        self._n = 0

    def append(self, index: ChunkIndex) -> None:
        builder = RecordBuilder()
        index.write(builder)
        self.append_record(builder.end())  # type: ignore[no-untyped-call]

    def append_record(self, record: bytes) -> None:
        """Append a chunk index already serialised (:class:`_MessageAppender` packs them)."""
        self._data += record
        self._n += 1

    def __len__(self) -> int:
        return self._n

    def __iter__(self) -> Iterator[_RawRecords]:
        if self._data:
            yield _RawRecords(bytes(self._data))

    @property
    def nbytes(self) -> int:
        return len(self._data)


_CHUNK_INDEXES_ATTR = "_Writer__chunk_indices"  # mcap 1.x; checked before it is replaced


_MESSAGE_HEAD = struct.Struct("<BQHIQQ")  # opcode, record length, channel, sequence, times
_MESSAGE_OPCODE = 0x05
_CHUNK_HEAD = struct.Struct("<BQQQQII")  # opcode, length, times, size, CRC, name length
_CHUNK_OPCODE = 0x06
_INDEX_HEAD = struct.Struct("<BQHI")  # opcode, record length, channel, entries length
_INDEX_OPCODE = 0x07
_U64 = struct.Struct("<Q")
_COMPRESSION_NAMES = {CompressionType.ZSTD: "zstd", CompressionType.LZ4: "lz4",
                      CompressionType.NONE: ""}
_PRIVATE = "_Writer__"  # the name-mangled prefix of mcap.writer.Writer's private attributes
_MESSAGE_FIXED = 22  # channel(2) + sequence(4) + log_time(8) + publish_time(8)
_BLANK_HEAD = bytes(_MESSAGE_HEAD.size)  # a message's head, packed once its length is known
_RECORD_HEAD = struct.Struct("<BQ")  # opcode, record length
_CHUNK_INDEX_OPCODE = 0x08
_CHUNK_INDEX_HEAD = struct.Struct("<QQQQI")  # times, chunk offset, length, offsets' length
_INDEX_OFFSET = struct.Struct("<HQ")  # channel, message index offset
_U64_U32 = struct.Struct("<QI")
_U64_U64 = struct.Struct("<QQ")
_MESSAGE_BODY = struct.Struct("<HIQQ")  # channel, sequence, log time, publish time
_IDS_MAX = 256  # spec objects a writer remembers by identity


class _MessageAppender:
    """``Writer.add_message`` for chunked files, with the chunk in progress kept here: its
    records in a ``bytearray`` and, per channel, its message index as a flat list of (log
    time, offset) pairs. Per message only those two grow (:meth:`McapFileWriter.add` and
    ``add_typed``); the chunk's times and the file's statistics are worked out from the index
    when the chunk is closed (:meth:`finalize`, for full chunks, flushes and the finish), with
    the same results as the library's per-message updates. The file is byte for byte the
    library's (``tests/unit/test_mcapio.py``). A live recorder adds a message per raw chunk and
    per record, and the library's path was a third of its time.

    Schemas and channels are registered by the library into its own chunk builder, which may
    close the chunk when that makes it full: :meth:`lend` hands the chunk in progress to the
    builder for that and :meth:`take_back` takes what is left back.

    Made only when the writer's internals are the ones this was written against (mcap 1.x);
    otherwise :meth:`make` returns ``None`` and the library's own path is used."""

    def __init__(self, writer: Writer) -> None:
        self._stats = getattr(writer, _PRIVATE + "statistics")
        self._builder = getattr(writer, _PRIVATE + "chunk_builder")
        self.chunk_size: int = getattr(writer, _PRIVATE + "chunk_size")
        self._stream = getattr(writer, _PRIVATE + "stream")
        self._flush_records = getattr(writer, _PRIVATE + "flush")
        self._chunk_indices = getattr(writer, _CHUNK_INDEXES_ATTR)
        self._crcs: bool = getattr(writer, _PRIVATE + "enable_crcs")
        self._index_messages = bool(getattr(writer, _PRIVATE + "index_types") & IndexType.MESSAGE)
        compression = getattr(writer, _PRIVATE + "compression")
        self._compression = _COMPRESSION_NAMES[compression]
        # One compressor for the file: ``zstandard.compress`` (the library's call) makes a new
        # one per chunk, whose set-up cost more than compressing a chunk of records. Same
        # parameters (level 3), same frames (checked in the tests).
        self._zstd = (zstandard.ZstdCompressor(level=3)
                      if compression == CompressionType.ZSTD else None)
        self._data_crcs: bool = getattr(writer, _PRIVATE + "enable_data_crcs")
        self.buf = bytearray()  # the records of the chunk in progress
        self.index: dict[int, list[int]] = {}  # channel -> [log_time, offset, ...], first use first
        # What is not yet known to be safe (McapFileWriter.unsettled), when ``keep``: the
        # chunks closed since the last settle, each with the offset its unsettled records start
        # at, and that offset in the chunk in progress.
        self.keep = False
        self.kept: list[tuple[bytearray, int]] = []
        self.settled = 0

    @classmethod
    def make(cls, writer: Writer) -> _MessageAppender | None:
        try:
            appender = cls(writer)
            builder = appender._builder
            ok = (builder is not None and isinstance(builder.record_writer, RecordBuilder)
                  and hasattr(builder.record_writer, "_buffer")
                  and isinstance(builder.message_indices, dict)
                  and hasattr(builder, "num_messages")
                  and hasattr(builder, "message_start_time")
                  and hasattr(appender._stats, "channel_message_counts")
                  and hasattr(appender._stats, "chunk_count")
                  and hasattr(appender._stats, "message_start_time")
                  and hasattr(builder, "reset") and hasattr(appender._stream, "tell")
                  and callable(appender._flush_records)
                  and appender._compression is not None
                  and not appender._data_crcs)  # a data CRC is kept by the library's writes
        except (AttributeError, KeyError):
            ok = False
        if not ok:
            log.debug("mcap writer internals changed: the library's add_message is used")
            return None
        return appender

    def _times(self, index: dict[int, list[int]]) -> tuple[int, int, int]:
        """Messages, earliest and latest log time of a chunk's ``index`` (latest at least 0,
        as the library's running maximum starts there)."""
        n = 0
        start = end = 0
        for entries in index.values():
            logs = entries[0::2]
            lo, hi = min(logs), max(logs)
            if n == 0 or lo < start:
                start = lo
            if hi > end:
                end = hi
            n += len(logs)
        return n, start, end

    def _count(self, index: dict[int, list[int]], n: int, start: int, end: int) -> None:
        """Add a closed chunk's messages to the file's statistics."""
        st = self._stats
        if st.message_count == 0 or start < st.message_start_time:
            st.message_start_time = start
        if end > st.message_end_time:
            st.message_end_time = end
        counts = st.channel_message_counts
        for cid, entries in index.items():
            counts[cid] += len(entries) // 2
        st.message_count += n

    def lend(self) -> None:
        """Put the chunk in progress into the library's chunk builder (before a schema or a
        channel is registered there), as the library would hold it."""
        cb = self._builder
        cb.record_writer.write(self.buf)
        n, start, end = self._times(self.index)
        cb.num_messages = n
        cb.message_start_time, cb.message_end_time = start, end
        cb.message_indices.clear()
        for cid, entries in self.index.items():
            cb.message_indices[cid] = MessageIndex(
                channel_id=cid, records=list(zip(entries[0::2], entries[1::2], strict=True)))

    def take_back(self, failed: bool) -> None:
        """Take the chunk in progress back from the library's builder after :meth:`lend` (the
        library closed it if the registration made it full; ``failed``: writing it failed)."""
        cb = self._builder
        rest = cb.record_writer.end()
        if failed or (self.index and cb.num_messages == 0):  # closed by the library
            if self.index:
                self._count(self.index, *self._times(self.index))
                if self.keep:
                    self.kept.append((self.buf, self.settled))
            self.index, self.settled = {}, 0
            self.buf = bytearray() if failed else bytearray(rest)
        else:
            self.buf = bytearray(rest)  # ours, then the schema and channel records
        cb.reset()

    def finalize(self) -> None:
        """Close the chunk in progress, as ``Writer.__finalize_chunk`` does (the chunk record,
        its message indexes and its chunk index, the same bytes in the same two writes), with
        each record packed by ``struct`` at once instead of field by field."""
        index = self.index
        if not index:
            return
        n, start, end = self._times(index)
        self._count(index, n, start, end)
        self._stats.chunk_count += 1
        chunk_data = self.buf
        if self.keep:
            self.kept.append((chunk_data, self.settled))  # before anything can fail
        self.buf, self.index, self.settled = bytearray(), {}, 0
        if self._zstd is not None:
            compressed = self._zstd.compress(chunk_data)
        elif self._compression == "lz4":
            compressed = lz4.frame.compress(chunk_data)
        else:
            compressed = bytes(chunk_data)
        name = self._compression.encode()
        head = _CHUNK_HEAD.pack(
            _CHUNK_OPCODE, 8 + 8 + 8 + 4 + 4 + len(name) + 8 + len(compressed), start, end,
            len(chunk_data), zlib.crc32(chunk_data) if self._crcs else 0, len(name),
        )
        self._flush_records()  # nothing is waiting there; the library's order, to be sure
        chunk_start = self._stream.tell()
        self._stream.write(head + name + _U64.pack(len(compressed)) + compressed)
        chunk_length = self._stream.tell() - chunk_start
        offsets: dict[int, int] = {}
        indexes = bytearray()
        if self._index_messages:
            index_start = chunk_start + chunk_length
            for cid, entries in index.items():
                offsets[cid] = index_start + len(indexes)
                indexes += _INDEX_HEAD.pack(_INDEX_OPCODE, 6 + 8 * len(entries), cid,
                                            8 * len(entries))
                indexes += struct.pack(f"<{len(entries)}Q", *entries)
            if indexes:
                self._stream.write(indexes)
        if isinstance(self._chunk_indices, PackedChunkIndexes):  # ChunkIndex.write's bytes
            fields = (_CHUNK_INDEX_HEAD.pack(start, end, chunk_start, chunk_length,
                                             10 * len(offsets))
                      + b"".join(_INDEX_OFFSET.pack(cid, at) for cid, at in offsets.items())
                      + _U64_U32.pack(len(indexes), len(name)) + name
                      + _U64_U64.pack(len(compressed), len(chunk_data)))
            self._chunk_indices.append_record(
                _RECORD_HEAD.pack(_CHUNK_INDEX_OPCODE, len(fields)) + fields)
        else:
            self._chunk_indices.append(ChunkIndex(
                message_start_time=start, message_end_time=end, chunk_start_offset=chunk_start,
                chunk_length=chunk_length, message_index_offsets=offsets,
                message_index_length=len(indexes), compression=self._compression,
                compressed_size=len(compressed), uncompressed_size=len(chunk_data),
            ))


class McapFileWriter:
    """One MCAP file being written.

    Args:
        path: the file to create; it must not exist.
        chunk_size_bytes: chunk size target; chunks are also closed by :meth:`flush`.
        compression: ``zstd``, ``lz4`` or ``none``.
        library: the writer identification in the MCAP header.
        file: the file to write through, already created at ``path`` (default: a new
            :class:`ExactFile`).
        packed_index: keep the chunk indexes packed (:class:`PackedChunkIndexes`): the writer
            holds one per chunk until :meth:`finish`, and a live recorder closes a chunk at
            every flush. Skipped, with a debug log, if the mcap library changed its internals.
        keep_unsettled: keep what was added since the last :meth:`settle` (the uncompressed
            chunks), for :meth:`unsettled`; whoever sets it calls :meth:`settle` regularly.

    Raises:
        FileExistsError: if ``path`` exists (recordings are never overwritten).
        OSError: if the header cannot be written.
    """

    def __init__(
        self,
        path: Path,
        *,
        chunk_size_bytes: int = 64 * 1024,
        compression: str = "zstd",
        library: str = "groundstation",
        file: WritableFile | None = None,
        packed_index: bool = True,
        keep_unsettled: bool = False,
    ) -> None:
        self.path = path
        self._file: WritableFile = file if file is not None else ExactFile(path)
        self._writer = Writer(
            self._file,  # type: ignore[arg-type]
            chunk_size=chunk_size_bytes, compression=_COMPRESSION[compression],
        )
        self.chunk_indexes: PackedChunkIndexes | None = None
        if packed_index:
            current = getattr(self._writer, _CHUNK_INDEXES_ATTR, None)
            if isinstance(current, list) and not current:
                self.chunk_indexes = PackedChunkIndexes()
                setattr(self._writer, _CHUNK_INDEXES_ATTR, self.chunk_indexes)
            else:
                log.debug("mcap writer internals changed: chunk indexes not packed")
        self._writer.start(profile="", library=library)
        self._appender = _MessageAppender.make(self._writer)
        self._keep = keep_unsettled
        if self._appender is not None:
            self._appender.keep = keep_unsettled
        self._schemas: dict[str, int] = {}
        self._channels: dict[ChannelSpec, int] = {}
        self._ids: dict[int, int] = {}  # id(spec) -> channel id
        self._specs: dict[int, ChannelSpec] = {}  # channel id -> the first spec seen
        self._specs_seen: list[ChannelSpec] = []
        # unsettled messages the chunks do not hold (the library's path; a failed channel's)
        self._loose: list[tuple[ChannelSpec, bytes, int, int]] = []
        self._finished = False
        self.messages = 0
        self.data_bytes = 0

    def __enter__(self) -> McapFileWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.finish()

    def channel_id(self, spec: ChannelSpec) -> int:
        """The channel id for ``spec``, registering schema and channel on first use."""
        cid = self._channels.get(spec)
        if cid is None:
            appender = self._appender
            if appender is not None:
                appender.lend()
            try:
                schema_id = 0
                if spec.schema_name:
                    key = spec.schema_name + "\0" + spec.schema_data.decode()
                    schema_id = self._schemas.get(key, 0)
                    if not schema_id:
                        schema_id = self._writer.register_schema(
                            spec.schema_name, spec.schema_encoding, spec.schema_data
                        )
                        self._schemas[key] = schema_id
                cid = self._writer.register_channel(spec.topic, spec.message_encoding, schema_id)
            except BaseException:
                if appender is not None:
                    appender.take_back(failed=True)
                raise
            if appender is not None:
                appender.take_back(failed=False)
            self._channels[spec] = cid
            self._specs.setdefault(cid, spec)
        return cid

    def _channel_of(self, spec: ChannelSpec, message: Callable[[], bytes], log_time_ns: int,
                    publish_time_ns: int) -> int:
        """The channel id of ``spec`` for a message being added; if registering it fails, the
        message (``message()`` is its data) stays unsettled like the ones before it."""
        # Channels by the spec object's identity first: hashing the dataclass is a Python
        # call per message. ``_specs_seen`` holds every spec seen, so no id is reused meanwhile.
        cid = self._ids.get(id(spec))
        if cid is None:
            try:
                cid = self.channel_id(spec)
            except OSError:
                if self._keep:
                    self._loose.append((spec, message(), log_time_ns, publish_time_ns))
                raise
            if len(self._specs_seen) >= _IDS_MAX:  # a caller making a spec per message
                self._ids.clear()
                self._specs_seen.clear()
            self._ids[id(spec)] = cid
            self._specs_seen.append(spec)
        return cid

    def add(self, spec: ChannelSpec, data: bytes, log_time_ns: int, publish_time_ns: int) -> bool:
        """Add one message on the channel described by ``spec``; True if that closed a chunk
        (the file grew)."""
        cid = self._ids.get(id(spec))
        if cid is None:
            cid = self._channel_of(spec, lambda: data, log_time_ns, publish_time_ns)
        appender = self._appender
        if appender is None:
            if self._keep:
                self._loose.append((spec, data, log_time_ns, publish_time_ns))
            chunks = self._writer_chunks()
            self._writer.add_message(cid, log_time=log_time_ns, data=data,
                                     publish_time=publish_time_ns,
                                     sequence=self.messages & 0xFFFFFFFF)
            self.messages += 1
            self.data_bytes += len(data)
            return self._writer_chunks() != chunks
        buf = appender.buf
        entries = appender.index.get(cid)
        if entries is None:
            entries = appender.index[cid] = []
        entries += (log_time_ns, len(buf))
        buf += _MESSAGE_HEAD.pack(_MESSAGE_OPCODE, _MESSAGE_FIXED + len(data), cid,
                                  self.messages & 0xFFFFFFFF, log_time_ns, publish_time_ns)
        buf += data
        full = len(buf) > appender.chunk_size
        if full:
            appender.finalize()
        self.messages += 1
        self.data_bytes += len(data)
        return full

    def add_typed(self, spec: ChannelSpec, record: Any, log_time_ns: int,
                  publish_time_ns: int) -> bool:
        """:meth:`add` of ``jsonio.dumps_typed(record)``, encoded straight into the chunk."""
        appender = self._appender
        if appender is None:
            return self.add(spec, jsonio.dumps_typed(record), log_time_ns, publish_time_ns)
        cid = self._ids.get(id(spec))
        if cid is None:
            cid = self._channel_of(spec, lambda: jsonio.dumps_typed(record), log_time_ns,
                                   publish_time_ns)
        buf = appender.buf
        offset = len(buf)
        buf += _BLANK_HEAD
        try:
            jsonio.append_typed(record, buf)
            n = len(buf) - offset - _MESSAGE_HEAD.size
            _MESSAGE_HEAD.pack_into(buf, offset, _MESSAGE_OPCODE, _MESSAGE_FIXED + n, cid,
                                    self.messages & 0xFFFFFFFF, log_time_ns, publish_time_ns)
        except BaseException:  # a value that cannot be written: the chunk stays whole
            del buf[offset:]
            raise
        entries = appender.index.get(cid)
        if entries is None:
            entries = appender.index[cid] = []
        entries += (log_time_ns, offset)
        full = len(buf) > appender.chunk_size
        if full:
            appender.finalize()
        self.messages += 1
        self.data_bytes += n
        return full

    def unsettled(self) -> list[tuple[ChannelSpec, bytes, int, int]]:
        """Every message added since the last :meth:`settle` (in order, as ``(spec, data,
        log_time_ns, publish_time_ns)``): what a failed write may have lost. Read back from
        the chunks, which hold them anyway (no second copy is kept per message)."""
        if not self._keep:
            raise RuntimeError("the writer was made without keep_unsettled")
        out: list[tuple[ChannelSpec, bytes, int, int]] = []
        appender = self._appender
        if appender is not None:
            for chunk, start in (*appender.kept, (appender.buf, appender.settled)):
                self._messages_of(chunk, start, out)
        out += self._loose
        return out

    def _messages_of(self, chunk: bytearray, pos: int,
                     out: list[tuple[ChannelSpec, bytes, int, int]]) -> None:
        view = memoryview(chunk)
        end = len(chunk)
        while pos < end:
            opcode, length = _RECORD_HEAD.unpack_from(chunk, pos)
            body = pos + _RECORD_HEAD.size
            if opcode == _MESSAGE_OPCODE:  # else a schema or a channel
                cid, _, log_ns, publish_ns = _MESSAGE_BODY.unpack_from(chunk, body)
                out.append((self._specs[cid], bytes(view[body + _MESSAGE_FIXED:body + length]),
                            log_ns, publish_ns))
            pos = body + length
        view.release()

    def settle(self) -> None:
        """Everything added so far is safely in the file (flushed, and the file is still
        where it was): forget it."""
        appender = self._appender
        if appender is not None:
            appender.kept.clear()
            appender.settled = len(appender.buf)
        self._loose.clear()

    def _writer_chunks(self) -> int:
        """Chunks the library's writer has closed (when it adds the messages itself)."""
        stats = getattr(self._writer, _PRIVATE + "statistics", None)
        return int(getattr(stats, "chunk_count", 0))

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        self._writer.add_metadata(name, data)

    def flush(self) -> None:
        """Close the chunk in progress and flush the file (no fsync)."""
        if not self._finished:
            if self._appender is not None:
                self._appender.finalize()
            self._writer.flush()  # type: ignore[no-untyped-call]

    @property
    def size_bytes(self) -> int:
        """Bytes written to the file so far (excluding the chunk in progress)."""
        return self._file.tell()

    def finish(self) -> None:
        """Write the summary and footer and close the file; safe to call twice."""
        if self._finished:
            return
        self._finished = True
        try:
            if self._appender is not None:
                self._appender.finalize()
            self._writer.finish()  # type: ignore[no-untyped-call]
        finally:
            self._file.close()

    def abandon(self, good_size: int) -> None:
        """Give the file up after a failed write: cut it back to ``good_size`` (the size after
        the last successful :meth:`flush`, a record boundary) and close it without a summary.
        What remains reads like the file of a killed writer, minus the torn tail."""
        self._finished = True
        try:
            os.truncate(self.path, good_size)
        except OSError as err:
            log.warning("%s: cannot cut back to %d bytes: %s", self.path, good_size, err)
        with contextlib.suppress(OSError):
            self._file.close()

    def forsake(self) -> None:
        """Close without a summary, leaving the path alone: the file was deleted or replaced
        under the writer, so whatever the path names now is not this writer's to cut."""
        self._finished = True
        with contextlib.suppress(OSError):
            self._file.close()

    def discard(self) -> None:
        """Close and delete a file this writer created and that holds nothing needed."""
        self._finished = True
        with contextlib.suppress(OSError):
            self._file.close()
        with contextlib.suppress(OSError):
            self.path.unlink()


# -- reading --------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class McapMessage:
    """One message as read back, with its channel's description."""

    topic: str
    message_encoding: str
    schema_name: str
    log_time_ns: int
    publish_time_ns: int
    sequence: int
    data: bytes


@dataclass(slots=True)
class ReadReport:
    """Filled in while :func:`iter_messages` runs: how the file ended."""

    finished: bool = False
    truncated: bool = False
    error: str = ""
    messages: int = 0
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)


def iter_messages(
    path: Path | str | BinaryIO,
    topics: Iterable[str] | None = None,
    report: ReadReport | None = None,
) -> Iterator[McapMessage]:
    """Every message of an MCAP file in file order, finished or not.

    A file whose writer was killed ends in a torn record; everything before the last complete
    chunk is returned and the tail is reported in ``report`` (not raised).

    Args:
        path: the MCAP file, or a binary file open at its start (left open; its position
            tells how far reading has gone, for progress).
        topics: only these topics (all when ``None``).
        report: optional :class:`ReadReport` filled in as reading goes.
    """
    wanted = None if topics is None else set(topics)
    rep = report if report is not None else ReadReport()
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    with _opened(path) as f:
        records = StreamReader(f, skip_magic=False).records
        while True:
            try:
                record = next(records)
            except StopIteration:
                rep.finished = True
                return
            except Exception as err:
                # A torn tail fails in the record parser, the decompressor or a length check,
                # depending on where the writer stopped: all of them end the readable part.
                rep.truncated = True
                rep.error = f"{type(err).__name__}: {err}"
                log.debug("%s: readable part ends: %s", path, rep.error)
                return
            if isinstance(record, Message):
                ch = channels.get(record.channel_id)
                if ch is None:
                    continue
                if wanted is not None and ch.topic not in wanted:
                    continue
                schema = schemas.get(ch.schema_id)
                rep.messages += 1
                yield McapMessage(
                    ch.topic, ch.message_encoding, schema.name if schema else "",
                    record.log_time, record.publish_time, record.sequence, bytes(record.data),
                )
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Metadata):
                rep.metadata[record.name] = dict(record.metadata)


@contextlib.contextmanager
def _opened(source: Path | str | BinaryIO) -> Iterator[BinaryIO]:
    """``source`` opened for reading if it is a path; a file object as it is (not closed)."""
    if isinstance(source, (str, os.PathLike)):
        with Path(source).open("rb") as f:
            yield f
    else:
        yield source


def read_head_metadata(path: Path | str) -> dict[str, dict[str, str]]:
    """The metadata records written before the first chunk (where the recorder puts the
    session's), without reading the rest of the file: a few hundred bytes, finished or not.

    Returns an empty dict for a file that is not MCAP or is torn before its first chunk.
    """
    out: dict[str, dict[str, str]] = {}
    with Path(path).open("rb") as f:
        records = StreamReader(f, skip_magic=False, emit_chunks=True).records
        try:
            for record in records:
                if isinstance(record, Metadata):
                    out[record.name] = dict(record.metadata)
                elif isinstance(record, (Chunk, Message, DataEnd)):
                    break
        except Exception as err:  # a torn or foreign file: what was read is all there is
            log.debug("%s: head ends: %s", path, err)
    return out


def iter_raw_chunks(path: Path | str | BinaryIO) -> Iterator[tuple[bytes, int]]:
    """The ``/ubx/raw`` chunks of a recording as ``(data, log_time_ns)``, finished or not.

    Concatenating the data gives exactly the bytes the daemon received, in order.
    """
    for msg in iter_messages(path, topics=(RAW_TOPIC,)):
        yield msg.data, msg.log_time_ns


def read_metadata(path: Path | str) -> dict[str, dict[str, str]]:
    """The metadata records of a recording (name -> key/value), finished or not."""
    rep = ReadReport()
    collections.deque(iter_messages(path, topics=(), report=rep), maxlen=0)  # read to the end
    return rep.metadata


@dataclass(frozen=True, slots=True)
class SummaryInfo:
    """The summary section of a finished file."""

    message_count: int
    chunk_count: int
    start_time_ns: int
    end_time_ns: int
    messages_by_topic: dict[str, int]


def read_summary(path: Path | str) -> SummaryInfo | None:
    """The summary of a finished recording via the seeking reader; ``None`` if unfinished."""
    with Path(path).open("rb") as f:
        try:
            summary = make_reader(f).get_summary()
        except Exception as err:  # an unfinished file's tail is not a footer: anything may fail
            log.debug("%s: no summary: %s", path, err)
            return None
    if summary is None or summary.statistics is None:
        return None
    stats = summary.statistics
    by_topic: dict[str, int] = {}
    for cid, n in stats.channel_message_counts.items():
        topic = summary.channels[cid].topic
        by_topic[topic] = by_topic.get(topic, 0) + n
    return SummaryInfo(
        stats.message_count, stats.chunk_count, stats.message_start_time,
        stats.message_end_time, by_topic,
    )
