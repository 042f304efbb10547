"""Recordings moved over the bus in chunks: the rules both ends share (sans-I/O but for reading
a file to hash it).

The daemon serves each finished recording file on ``groundstation/<station>/q/recording/
<session_id>`` (:mod:`groundstation.live.serve`); a solver fetches it chunk by chunk
(:mod:`groundstation.solve.fetch`). A query names ``file`` (a plain file name of the session),
``offset`` and ``length``; the reply carries the bytes and, as its attachment, a JSON object
with ``file``, ``offset``, ``length``, ``size`` (the whole file's) and ``crc32`` of the bytes.

Why CRC-32 (``zlib.crc32``) and not CRC-32C: no library kept in the project computes CRC-32C
and adding one for this is not worth it. The chunk check only has to catch a damaged or
misplaced chunk before it is written (CRC-32 and CRC-32C detect the same burst lengths; only
their hardware speed differs, and zlib's runs at several GB/s here); the proof that the file is
the daemon's file, byte for byte, is the whole file's SHA-256 announced in the ``session``
message.
"""

from __future__ import annotations

import hashlib
import re
import zlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from groundstation import jsonio

CHUNK_BYTES = 256 * 1024
"""What a solver asks for at once (announced per file as ``chunk_bytes``)."""
MAX_LENGTH = 1 << 20
"""The most a single query may ask for; more is refused (a peer must not make the daemon read
and send a whole recording in one reply)."""
SESSION_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,127}")
"""A session id usable as one chunk of a key expression (no ``/``, ``*``, ``$``, ``?``, ``#``)."""
FILE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,199}\.mcap")
"""A served file's name: a plain recording name, never a path (``storage/naming.py`` makes
``<station>_<UTC>[_n].mcap``)."""
SHA256 = re.compile(r"[0-9a-f]{64}")


class BadRequest(ValueError):
    """A chunk query or a reply that breaks the rules; the text says which, in one line."""


@dataclass(frozen=True, slots=True)
class Request:
    """One chunk query: ``length`` bytes of ``file`` from ``offset``."""

    file: str
    offset: int
    length: int

    def parameters(self) -> dict[str, str]:
        """As the query's selector parameters."""
        return {"file": self.file, "offset": str(self.offset), "length": str(self.length)}


def _int(params: Mapping[str, str | None], name: str, lo: int, hi: int) -> int:
    text = params.get(name)
    # ASCII digits only: str.isdigit() also takes "²" or "٣", which int() refuses or reads
    if text is None or not (text.isascii() and text.isdigit()) or len(text) > 19:
        raise BadRequest(f"{name}: expected an integer in [{lo}, {hi}], got {str(text)[:40]!r}")
    value = int(text)
    if not lo <= value <= hi:
        raise BadRequest(f"{name}: {value} outside [{lo}, {hi}]")
    return value


def parse_request(params: Mapping[str, str | None]) -> Request:
    """A query's parameters as a :class:`Request`.

    Raises:
        BadRequest: a file name that is not a plain recording name, a negative or non-integer
            offset, a length outside ``[1, MAX_LENGTH]``.
    """
    name = params.get("file") or ""
    if not FILE_NAME.fullmatch(name):
        raise BadRequest(f"file: {name[:80]!r} is not a recording file name")
    return Request(name, _int(params, "offset", 0, 1 << 62), _int(params, "length", 1,
                                                                     MAX_LENGTH))


def crc32(data: bytes) -> int:
    """The chunk checksum (module docstring: why CRC-32)."""
    return zlib.crc32(data) & 0xFFFFFFFF


def chunk_attachment(name: str, offset: int, data: bytes, size: int) -> bytes:
    """The reply's attachment for ``data`` read at ``offset`` of a file of ``size`` bytes."""
    return jsonio.dumps({"file": name, "offset": offset, "length": len(data), "size": size,
                         "crc32": crc32(data)})


def check_chunk(request: Request, payload: bytes, attachment: bytes | None) -> None:
    """A reply is the chunk asked for, undamaged.

    Raises:
        BadRequest: the attachment is missing or names another file or offset, the length is
            not the one announced, or the CRC does not match the bytes.
    """
    try:
        meta = jsonio.loads(attachment or b"")
    except ValueError as err:
        raise BadRequest(f"reply attachment is not JSON: {err}") from err
    if not isinstance(meta, dict):
        raise BadRequest("reply attachment is not a JSON object")
    if meta.get("file") != request.file or meta.get("offset") != request.offset:
        raise BadRequest(f"reply for {meta.get('file')!r} at {meta.get('offset')!r}, asked "
                         f"{request.file!r} at {request.offset}")
    if meta.get("length") != len(payload):
        raise BadRequest(f"reply of {len(payload)} bytes announces {meta.get('length')!r}")
    if meta.get("crc32") != crc32(payload):
        raise BadRequest(f"CRC mismatch in the chunk at {request.offset}")


def sha256_file(path: Path, chunk_bytes: int = 1 << 20) -> str:
    """SHA-256 of a file, streamed (hex)."""
    h = hashlib.sha256()
    with path.open("rb") as f:
        while block := f.read(chunk_bytes):
            h.update(block)
    return h.hexdigest()


def check_entry(entry: Any) -> dict[str, Any]:
    """One ``recordings[]`` entry of a ``session`` message: ``name``, ``size``, ``sha256``,
    ``chunk_bytes`` (:func:`groundstation.messages.check` calls this).

    Raises:
        BadRequest: what is wrong.
    """
    if not isinstance(entry, dict):
        raise BadRequest("a recordings entry is not an object")
    name, size, digest, chunk = (entry.get(k) for k in ("name", "size", "sha256",
                                                         "chunk_bytes"))
    if not isinstance(name, str) or not FILE_NAME.fullmatch(name):
        raise BadRequest(f"recordings: {str(name)[:80]!r} is not a recording file name")
    if not isinstance(size, int) or isinstance(size, bool) or not 0 <= size <= 1 << 50:
        raise BadRequest(f"recordings: size {size!r} is not a byte count")
    if not isinstance(digest, str) or not SHA256.fullmatch(digest):
        raise BadRequest("recordings: sha256 is not 64 lowercase hex digits")
    if (not isinstance(chunk, int) or isinstance(chunk, bool)
            or not 1 <= chunk <= MAX_LENGTH):
        raise BadRequest(f"recordings: chunk_bytes {chunk!r} outside [1, {MAX_LENGTH}]")
    return entry
