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

import bisect
import collections
import contextlib
import errno
import logging
import os
import struct
import zlib
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, BinaryIO, Protocol

import lz4.frame  # type: ignore[import-untyped]
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.reader import make_reader
from mcap.records import (
    Chunk,
    ChunkIndex,
    DataEnd,
    Message,
    MessageIndex,
    Metadata,
)
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, IndexType, Writer

from groundstation import jsonio
from groundstation.storage.skipped import Skipped

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
    """Filled in while :func:`iter_messages` runs: how the file ended and what was skipped."""

    finished: bool = False
    """The footer was read: the file was finished by its writer."""
    truncated: bool = False
    """The file ends in a torn record (its writer stopped mid-write): read up to there."""
    error: str = ""
    messages: int = 0
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    skipped: list[Skipped] = field(default_factory=list)
    """Damaged stretches read past (each one also logged as a warning)."""
    orphan_messages: int = 0
    """Messages on channels defined only in a skipped stretch: their topic is unknown, so
    they are not returned (counted, and logged as a warning)."""


class _Damage(Exception):
    """A record that cannot be read where it stands."""

    def __init__(self, reason: str, *, torn: bool = False) -> None:
        super().__init__(reason)
        self.reason = reason
        self.torn = torn
        """The record runs past the end of the file: what a killed writer leaves."""


_MAGIC = b"\x89MCAP0\r\n"
_OP_FOOTER = 0x02
_OP_SCHEMA = 0x03
_OP_CHANNEL = 0x04
_OP_METADATA = 0x0C
_OP_DATA_END = 0x0F
_SKIPPED_OPS = frozenset({0x01, 0x08, 0x09, 0x0A, 0x0B, 0x0D, 0x0E})
"""Header, chunk index, attachment and the summary's records: nothing to read in them here."""
_RECORD_LIMIT = 1 << 29
"""A longer record is damage: the recorder's chunks are at most 256 MiB (its bound)."""
_CHUNK_FIXED = struct.Struct("<QQQII")  # times, uncompressed size, CRC, compression name length
_CHUNK_MIN = _CHUNK_FIXED.size + 8  # + records length
_CHUNK_INDEX_FIXED = struct.Struct("<QQQQ")  # times, chunk start, chunk length
_FOOTER = struct.Struct("<BQQQI")  # opcode, length, summary start, offsets start, CRC
_FOOTER_TAIL = _FOOTER.size + len(_MAGIC)
_DATA_END_SIZE = _RECORD_HEAD.size + 4
_COMPRESSIONS = (b"", b"zstd", b"lz4")
_ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"
_LZ4_MAGIC = b"\x04\x22\x4d\x18"
_SCAN_BLOCK = 1 << 20
_SCAN_OVERLAP = _RECORD_HEAD.size + _CHUNK_MIN + 16 + 4


def _string(buf: bytes, pos: int, end: int) -> tuple[str, int]:
    """A length-prefixed UTF-8 string of ``buf`` at ``pos`` and the position after it."""
    if pos + 4 > end:
        raise _Damage("a string runs past its record")
    (n,) = struct.unpack_from("<I", buf, pos)
    pos += 4
    if pos + n > end:
        raise _Damage("a string runs past its record")
    try:
        return buf[pos : pos + n].decode(), pos + n
    except UnicodeDecodeError as err:
        raise _Damage("a string is not UTF-8") from err


def _string_map(buf: bytes, pos: int, end: int) -> tuple[dict[str, str], int]:
    if pos + 4 > end:
        raise _Damage("a map runs past its record")
    (n,) = struct.unpack_from("<I", buf, pos)
    pos += 4
    stop = pos + n
    if stop > end:
        raise _Damage("a map runs past its record")
    out: dict[str, str] = {}
    while pos < stop:
        key, pos = _string(buf, pos, stop)
        out[key], pos = _string(buf, pos, stop)
    return out, pos


@dataclass(frozen=True, slots=True)
class _Channel:
    topic: str
    message_encoding: str
    schema_id: int


def _channel(buf: bytes, pos: int, end: int) -> tuple[int, _Channel]:
    if pos + 4 > end:
        raise _Damage("channel record cut")
    cid, schema_id = struct.unpack_from("<HH", buf, pos)
    topic, pos = _string(buf, pos + 4, end)
    encoding, pos = _string(buf, pos, end)
    _string_map(buf, pos, end)
    return cid, _Channel(topic, encoding, schema_id)


def _schema(buf: bytes, pos: int, end: int) -> tuple[int, str]:
    if pos + 2 > end:
        raise _Damage("schema record cut")
    (sid,) = struct.unpack_from("<H", buf, pos)
    name, _ = _string(buf, pos + 2, end)
    return sid, name


def _chunk_data(body: bytes) -> bytes:
    """The records of a chunk record's body, decompressed and checked against its CRC."""
    if len(body) < _CHUNK_MIN:
        raise _Damage("chunk header cut")
    _, _, size, crc, name_len = _CHUNK_FIXED.unpack_from(body, 0)
    at = _CHUNK_FIXED.size + name_len
    if name_len > 16 or at + 8 > len(body):
        raise _Damage("chunk header damaged")
    name = body[_CHUNK_FIXED.size : at]
    (records_len,) = _U64.unpack_from(body, at)
    at += 8
    if at + records_len != len(body) or size > _RECORD_LIMIT:
        raise _Damage("chunk header damaged (its lengths do not agree)")
    if name not in _COMPRESSIONS:
        raise _Damage(f"chunk compressed with unknown {name!r}")
    packed = memoryview(body)[at:]
    try:
        if name == b"zstd":
            # the frame's own size claim first: a damaged one must not allocate gigabytes
            claimed = zstandard.frame_content_size(packed)
            if claimed not in (-1, size):
                raise _Damage("chunk does not decompress (sizes disagree)")
            data = zstandard.ZstdDecompressor().decompress(packed, max_output_size=size)
        elif name == b"lz4":
            data = lz4.frame.decompress(bytes(packed))
        else:
            data = bytes(packed)
    except _Damage:
        raise
    except Exception as err:  # each decompressor has its own errors for damaged input
        raise _Damage(f"chunk does not decompress: {err}") from err
    if len(data) != size:
        raise _Damage("chunk decompresses to another size than its header says")
    if crc and zlib.crc32(data) != crc:
        raise _Damage("chunk CRC mismatch")
    return data


@dataclass(frozen=True, slots=True)
class _ChunkPlace:
    start: int
    length: int
    first_ns: int
    last_ns: int


@dataclass(frozen=True, slots=True)
class _FileSummary:
    """What a finished file's summary says about where its chunks are."""

    chunks: tuple[_ChunkPlace, ...]
    starts: tuple[int, ...]
    data_end: int | None
    """Where the data-end record stands (the data section's last record), if found."""
    channels: dict[int, _Channel]
    schemas: dict[int, str]

    def after(self, pos: int) -> tuple[int | None, list[_ChunkPlace]]:
        """Where reading goes on after damage at ``pos`` (the next chunk, or the data-end
        record), and the chunks lost in between (those starting at or after ``pos``, and one
        that ``pos`` falls inside)."""
        i = bisect.bisect_right(self.starts, pos)
        resume = self.starts[i] if i < len(self.starts) else self.data_end
        if resume is not None and resume <= pos:
            resume = None
        lost = [c for c in self.chunks
                if (pos <= c.start and (resume is None or c.start < resume))
                or c.start < pos < c.start + c.length]
        return resume, lost


class _Reader:
    """One linear pass over an MCAP file that reads past damage (:func:`iter_messages`)."""

    def __init__(self, f: BinaryIO, name: str, wanted: set[str] | None,
                 rep: ReadReport) -> None:
        self.f = f
        self.name = name
        self.wanted = wanted
        self.rep = rep
        self.start = f.tell()
        f.seek(0, os.SEEK_END)
        self.size = f.tell()
        f.seek(self.start)
        self.channels: dict[int, _Channel] = {}
        self.schemas: dict[int, str] = {}
        self.last_log_ns: int | None = None
        self.pending: Skipped | None = None  # damage read past, waiting for the next message
        self._summary: _FileSummary | None = None
        self._summary_read = False

    # -- the pass --

    def messages(self) -> Iterator[McapMessage]:
        rep = self.rep
        f = self.f
        if f.read(len(_MAGIC)) != _MAGIC:
            rep.truncated = True
            rep.error = "not an MCAP file (no magic at its start)"
            return
        pos: int | None = self.start + len(_MAGIC)
        data_ended = False
        try:
            while pos is not None:
                try:
                    got = self._record(pos)
                except _Damage as err:
                    if data_ended:  # the summary is damaged: every message was read
                        rep.truncated, rep.error = True, err.reason
                        log.debug("%s: summary unreadable after the data: %s", self.name,
                                  err.reason)
                        return
                    pos = self._skip(pos, err)
                    continue
                if got is None:  # the file ends on a record boundary
                    if not data_ended:
                        rep.truncated, rep.error = True, "ends without a footer"
                    return
                opcode, length, body = got
                after = pos + _RECORD_HEAD.size + length
                if data_ended or opcode in _SKIPPED_OPS:
                    if opcode == _OP_FOOTER:
                        rep.finished = True
                        return
                elif opcode == _CHUNK_OPCODE:
                    try:
                        msgs, data = self._chunk(body)
                    except _Damage as err:
                        pos = self._skip(pos, err)
                        continue
                    yield from self._deliver(msgs, data)
                elif opcode == _MESSAGE_OPCODE:  # outside a chunk (an unchunked file)
                    if len(body) < _MESSAGE_FIXED:
                        pos = self._skip(pos, _Damage("message record cut"))
                        continue
                    msg = (*_MESSAGE_BODY.unpack_from(body, 0), _MESSAGE_FIXED, len(body))
                    yield from self._deliver([msg], body)
                elif opcode == _INDEX_OPCODE:
                    if len(body) < 6 or struct.unpack_from("<I", body, 2)[0] + 6 != len(body):
                        pos = self._skip(pos, _Damage("message index damaged"))
                        continue
                elif opcode in (_OP_SCHEMA, _OP_CHANNEL, _OP_METADATA):
                    try:
                        self._definition(opcode, body, 0, len(body))
                    except _Damage as err:
                        pos = self._skip(pos, err)
                        continue
                elif opcode == _OP_DATA_END:
                    data_ended = True
                elif opcode == _OP_FOOTER:
                    rep.finished = True
                    return
                else:
                    pos = self._skip(pos, _Damage(f"record of unknown type 0x{opcode:02x}"))
                    continue
                pos = after
        finally:
            self._close_pending()
            if rep.orphan_messages:
                log.warning("%s: %d messages on channels defined only in the skipped bytes "
                            "could not be read (their topic is unknown)", self.name,
                            rep.orphan_messages)

    def _record(self, pos: int) -> tuple[int, int, bytes] | None:
        """``(opcode, length, body)`` of the record at ``pos`` (the body left empty for the
        records nothing is read from); ``None`` at the end of the file."""
        f = self.f
        if f.tell() != pos:
            f.seek(pos)
        head = f.read(_RECORD_HEAD.size)
        if not head:
            return None
        if len(head) < _RECORD_HEAD.size:
            raise _Damage("a record header cut by the end of the file", torn=True)
        opcode, length = _RECORD_HEAD.unpack(head)
        if length > self.size - pos - _RECORD_HEAD.size:
            raise _Damage(f"a record of {length:,} bytes runs past the end of the file",
                          torn=True)
        if length > _RECORD_LIMIT:
            raise _Damage(f"a record of {length:,} bytes (implausible)")
        if opcode in _SKIPPED_OPS:
            f.seek(length, os.SEEK_CUR)
            return opcode, length, b""
        return opcode, length, f.read(length)

    def _chunk(self, record: bytes) -> tuple[list[tuple[int, int, int, int, int, int]], bytes]:
        """A chunk's messages (``(channel, sequence, log ns, publish ns, data start, data
        end)`` into the returned data), its definitions taken in; all or nothing."""
        data = _chunk_data(record)
        msgs: list[tuple[int, int, int, int, int, int]] = []
        defs: list[tuple[int, int, int]] = []
        head = _RECORD_HEAD.unpack_from
        message = _MESSAGE_BODY.unpack_from
        pos, end = 0, len(data)
        while pos < end:
            if pos + _RECORD_HEAD.size > end:
                raise _Damage("chunk records cut")
            opcode, length = head(data, pos)
            body = pos + _RECORD_HEAD.size
            pos = body + length
            if pos > end:
                raise _Damage("a record runs past the end of its chunk")
            if opcode == _MESSAGE_OPCODE:
                if length < _MESSAGE_FIXED:
                    raise _Damage("message record cut")
                msgs.append((*message(data, body), body + _MESSAGE_FIXED, pos))
            elif opcode in (_OP_SCHEMA, _OP_CHANNEL):
                defs.append((opcode, body, pos))
        channels: dict[int, _Channel] = {}
        schemas: dict[int, str] = {}
        for opcode, a, b in defs:  # checked before any is taken in
            if opcode == _OP_CHANNEL:
                cid, ch = _channel(data, a, b)
                channels[cid] = ch
            else:
                sid, name = _schema(data, a, b)
                schemas[sid] = name
        self.channels.update(channels)
        self.schemas.update(schemas)
        return msgs, data

    def _definition(self, opcode: int, body: bytes, a: int, b: int) -> None:
        if opcode == _OP_CHANNEL:
            cid, ch = _channel(body, a, b)
            self.channels[cid] = ch
        elif opcode == _OP_SCHEMA:
            sid, name = _schema(body, a, b)
            self.schemas[sid] = name
        else:
            name, pos = _string(body, a, b)
            self.rep.metadata[name], _ = _string_map(body, pos, b)

    def _deliver(self, msgs: list[tuple[int, int, int, int, int, int]],
                 data: bytes) -> Iterator[McapMessage]:
        if not msgs:
            return
        if self.pending is not None:
            self._close_pending(msgs[0][2])
        rep = self.rep
        wanted = self.wanted
        channels = self.channels
        for cid, sequence, log_ns, publish_ns, a, b in msgs:
            ch = channels.get(cid)
            if ch is None:
                rep.orphan_messages += 1
                continue
            if wanted is not None and ch.topic not in wanted:
                continue
            rep.messages += 1
            yield McapMessage(ch.topic, ch.message_encoding, self.schemas.get(ch.schema_id, ""),
                              log_ns, publish_ns, sequence, data[a:b])
        self.last_log_ns = msgs[-1][2]

    # -- damage --

    def _skip(self, pos: int, err: _Damage) -> int | None:
        """Where reading goes on after damage at ``pos`` (``None``: nowhere), the skipped
        stretch noted."""
        summary = self._file_summary()
        lost: list[_ChunkPlace] = []
        if summary is not None:
            resume, lost = summary.after(pos)
        else:
            resume = self._scan(pos + 1)
        if resume is None and err.torn and summary is None:
            # the file of a killed writer: its last record cut short, nothing after it
            self.rep.truncated, self.rep.error = True, err.reason
            log.debug("%s: readable part ends at byte %d: %s", self.name, pos, err.reason)
            return None
        end = resume if resume is not None else self.size
        chunks = len(lost) if summary is not None else None
        first = min((c.first_ns for c in lost), default=None)
        last = max((c.last_ns for c in lost), default=None)
        p = self.pending
        if p is not None and p.end_byte == pos:  # one stretch, damaged twice over
            self.pending = replace(
                p, end_byte=end, to_end=resume is None,
                chunks=None if chunks is None else (p.chunks or 0) + chunks,
                lost_first_ns=_least(p.lost_first_ns, first),
                lost_last_ns=_most(p.lost_last_ns, last))
        else:
            self._close_pending()
            self.pending = Skipped(
                self.name, pos, end, err.reason, chunks=chunks, lost_first_ns=first,
                lost_last_ns=last, read_before_ns=self.last_log_ns, to_end=resume is None)
        if resume is None:
            self._close_pending()
        return resume

    def _close_pending(self, read_after_ns: int | None = None) -> None:
        p = self.pending
        if p is None:
            return
        self.pending = None
        p = replace(p, read_after_ns=read_after_ns)
        self.rep.skipped.append(p)
        said = (p.file, p.start_byte, p.end_byte)
        if said in _SAID or p.nothing_read:  # a tool reading the file again (solve: marks,
            # then RINEX), or nothing of the file readable: the tool's error says it
            log.debug("%s", p.describe())
            return
        if len(_SAID) >= 1000:
            _SAID.clear()
        _SAID.add(said)
        log.warning("%s", p.describe())

    def _scan(self, start: int) -> int | None:
        """The next place from ``start`` on where a whole, valid chunk begins (a linear
        reader's resynchronisation: a chunk opens with its opcode and a header whose lengths
        agree with each other and with the file, and it must decompress to its CRC)."""
        f = self.f
        pos = start
        while pos < self.size:
            f.seek(pos)
            buf = f.read(_SCAN_BLOCK + _SCAN_OVERLAP)
            limit = min(_SCAN_BLOCK, len(buf))
            i = buf.find(b"\x06", 0, limit)
            while i >= 0:
                if self._looks_like_chunk(buf, i, pos + i) and self._chunk_at(pos + i):
                    return pos + i
                i = buf.find(b"\x06", i + 1, limit)
            pos += _SCAN_BLOCK
        return None

    def _looks_like_chunk(self, buf: bytes, i: int, at: int) -> bool:
        """A chunk's header at ``buf[i:]`` (file offset ``at``) whose lengths agree."""
        at_name = i + _RECORD_HEAD.size + _CHUNK_FIXED.size
        if at_name + 16 + 8 > len(buf):  # only at the end of the file (the blocks overlap)
            return False
        _, length = _RECORD_HEAD.unpack_from(buf, i)
        if not _CHUNK_MIN <= length <= min(_RECORD_LIMIT, self.size - at - _RECORD_HEAD.size):
            return False
        first, last, _, _, name_len = _CHUNK_FIXED.unpack_from(buf, i + _RECORD_HEAD.size)
        if first > last or name_len > 16:
            return False
        name = buf[at_name : at_name + name_len]
        if name not in _COMPRESSIONS:
            return False
        (records_len,) = _U64.unpack_from(buf, at_name + name_len)
        if _CHUNK_MIN + name_len + records_len != length:
            return False
        # the data's own first bytes, before a whole chunk is read: a frame's magic number,
        # or (uncompressed) a record that may open a chunk
        data = at_name + name_len + 8
        head = buf[data : data + 4]
        if len(head) < 4:
            return True  # at the block's end: the whole chunk decides
        if name == b"zstd":
            return head == _ZSTD_MAGIC
        if name == b"lz4":
            return head == _LZ4_MAGIC
        return head[0] in (_OP_SCHEMA, _OP_CHANNEL, _MESSAGE_OPCODE)

    def _chunk_at(self, at: int) -> bool:
        try:
            got = self._record(at)
            if got is None or got[0] != _CHUNK_OPCODE:
                return False
            _chunk_data(got[2])
        except _Damage:
            return False
        return True

    def _file_summary(self) -> _FileSummary | None:
        """The chunk places a finished file's summary gives (read once, at the first damage);
        ``None`` for an unfinished file or a damaged summary."""
        if self._summary_read:
            return self._summary
        self._summary_read = True
        here = self.f.tell()
        try:
            self._summary = self._read_summary()
        except (_Damage, struct.error) as err:
            log.debug("%s: summary unusable: %s", self.name, err)
        finally:
            self.f.seek(here)
        if self._summary is not None:
            for cid, ch in self._summary.channels.items():  # lost with a damaged chunk
                self.channels.setdefault(cid, ch)
            for sid, name in self._summary.schemas.items():
                self.schemas.setdefault(sid, name)
        return self._summary

    def _read_summary(self) -> _FileSummary | None:
        f, size = self.f, self.size
        if size - self.start < len(_MAGIC) + _FOOTER_TAIL:
            return None
        f.seek(size - _FOOTER_TAIL)
        tail = f.read(_FOOTER_TAIL)
        opcode, length, summary_start, _, crc = _FOOTER.unpack_from(tail, 0)
        if tail[_FOOTER.size :] != _MAGIC or opcode != _OP_FOOTER or length != 20:
            return None
        if not self.start < summary_start <= size - _FOOTER_TAIL:
            return None
        f.seek(summary_start)
        data = f.read(size - _FOOTER_TAIL - summary_start)
        if crc and zlib.crc32(tail[: _FOOTER.size - 4], zlib.crc32(data)) != crc:
            raise _Damage("summary CRC mismatch")
        chunks: list[_ChunkPlace] = []
        channels: dict[int, _Channel] = {}
        schemas: dict[int, str] = {}
        pos, end = 0, len(data)
        while pos < end:
            opcode, rec_len = _RECORD_HEAD.unpack_from(data, pos)
            body = pos + _RECORD_HEAD.size
            pos = body + rec_len
            if pos > end:
                raise _Damage("summary record cut")
            if opcode == _CHUNK_INDEX_OPCODE:
                first, last, start, chunk_len = _CHUNK_INDEX_FIXED.unpack_from(data, body)
                chunks.append(_ChunkPlace(start, chunk_len, first, last))
            elif opcode == _OP_CHANNEL:
                cid, ch = _channel(data, body, pos)
                channels[cid] = ch
            elif opcode == _OP_SCHEMA:
                sid, name = _schema(data, body, pos)
                schemas[sid] = name
        if not chunks:
            return None
        chunks.sort(key=lambda c: c.start)
        data_end: int | None = summary_start - _DATA_END_SIZE
        f.seek(summary_start - _DATA_END_SIZE)
        if f.read(_RECORD_HEAD.size) != _RECORD_HEAD.pack(_OP_DATA_END, 4):
            data_end = None
        return _FileSummary(tuple(chunks), tuple(c.start for c in chunks), data_end,
                            channels, schemas)


_SAID: set[tuple[str, int, int]] = set()
"""Damaged stretches already warned about by this process: each is one warning line, however
often the file is read."""


def _least(a: int | None, b: int | None) -> int | None:
    return b if a is None else a if b is None else min(a, b)


def _most(a: int | None, b: int | None) -> int | None:
    return b if a is None else a if b is None else max(a, b)


def iter_messages(
    path: Path | str | BinaryIO,
    topics: Iterable[str] | None = None,
    report: ReadReport | None = None,
) -> Iterator[McapMessage]:
    """Every message of an MCAP file in file order, finished or not, read past damage.

    A file whose writer was killed ends in a torn record; everything before the last complete
    chunk is returned and the tail is reported in ``report`` (``truncated``, not raised).

    A damaged stretch in the middle (a chunk that fails its CRC or does not decompress, a
    record whose length or type makes no sense) is skipped and reading goes on: at the next
    chunk the summary names (a finished file), or else at the next place where a whole, valid
    chunk begins (a linear search). Each stretch is logged as one warning line naming the
    file's byte range and the time span lost, and listed in ``report.skipped``. Chunks are
    checked against their CRC, so damaged bytes are never returned as messages.

    Args:
        path: the MCAP file, or a binary file open at its start (left open; its position
            tells how far reading has gone, for progress).
        topics: only these topics (all when ``None``).
        report: optional :class:`ReadReport` filled in as reading goes.
    """
    wanted = None if topics is None else set(topics)
    rep = report if report is not None else ReadReport()
    name = str(path) if isinstance(path, (str, os.PathLike)) else str(getattr(path, "name", "?"))
    with _opened(path) as f:
        yield from _Reader(f, name, wanted, rep).messages()


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


def iter_raw_chunks(
    path: Path | str | BinaryIO, report: ReadReport | None = None,
    also: Mapping[str, Callable[[McapMessage], None]] | None = None,
) -> Iterator[tuple[bytes, int]]:
    """The ``/ubx/raw`` chunks of a recording as ``(data, log_time_ns)``, finished or not.

    Concatenating the data gives exactly the bytes the daemon received, in order (less any
    damaged stretch read past: ``report.skipped``). ``also`` reads other topics in the same
    pass: each of their messages goes to its topic's callback, in file order.
    """
    handlers = dict(also or {})
    for msg in iter_messages(path, topics=(RAW_TOPIC, *handlers), report=report):
        if msg.topic == RAW_TOPIC:
            yield msg.data, msg.log_time_ns
        else:
            handlers[msg.topic](msg)


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
