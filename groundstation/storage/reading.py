"""Reading recordings as byte chunks: the one reader behind ``run --file``, ``replay``,
``inspect``, ``rinex`` and ``solve``.

The format comes from the file's first bytes, never its name: MCAP (its ``/ubx/raw`` chunks,
finished or not, up to the last complete chunk), gzip (a ``.ubx.gz``) or anything else read as
raw bytes (``.ubx``, a serial log). Reading streams: nothing here holds more than one chunk of a
file in memory.

A session that the recorder split into parts (rotation by size, duration or chunk count, or a
new part after a write failure such as a full disk) is followed automatically. The rule:

- The parts of a session are the MCAP files in the same directory whose ``groundstation``
  metadata record (written at the head of every part by
  :class:`~groundstation.storage.session.SessionRecorder`) carries the same ``session_id``
  (``<station>_<start second>-<random token>``, unique even for two daemons of one station
  started in the same second: ``storage/naming.py``);
  their order is the metadata's ``part`` number (1, 2, ...), not the file name (a part opened in
  the same second as the previous one is named ``<stem>_1``, ``<stem>_2``, ... and ``_10`` sorts
  before ``_2``).
- Given a part, the reader reads that part and every later part of its session, in order. The
  first part (named after the session, ``<station>_<YYYYmmddTHHMMSSZ>.mcap``) therefore reads the
  whole session; a later part reads the session's tail from there (a long session's last hour
  without the hours before it).
- A ``.ubx`` (or ``.ubx.gz``) sidecar is followed the same way through its MCAP partner (same
  name, ``.mcap``, whose metadata names this sidecar): the sidecars of the later parts are read
  in the parts' order. Sidecars hold no reception times.
- A missing part (a number skipped) or a missing sidecar is reported as a warning and skipped:
  the bytes on either side of the hole are still read (the framer resynchronises).
- Parts are confined to the recording's own directory: a sidecar is a plain ``.ubx`` file
  name there (a metadata record naming ``../x`` or ``/etc/x`` is refused), and a part or a
  sidecar that is a symbolic link leading out of the directory is not followed. Each refusal
  is a warning naming the file and why; the solver service's ``recording_roots`` hold for
  every part read, not only the one it was given.
- A damaged stretch in the middle of an MCAP part (a chunk that fails its CRC or does not
  decompress, a broken record header) is read past (:func:`~groundstation.storage.mcapio.
  iter_messages`): one warning line names the byte range and the time span lost, and
  :attr:`Recording.skipped` lists them for the tools that report them (``inspect``).
- Any other file (no groundstation metadata, another program's MCAP, a plain log) is read alone.
  ``follow_parts=False`` reads only the given file.
"""

from __future__ import annotations

import gzip
import logging
import os
import stat
import zlib
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO, Literal

from groundstation.errors import InputError
from groundstation.storage.skipped import Skipped

if TYPE_CHECKING:
    from groundstation.storage.mcapio import McapMessage

log = logging.getLogger("groundstation.reading")

CHUNK_BYTES = 1 << 16
MCAP_MAGIC = b"\x89MCAP0\r\n"
GZIP_MAGIC = b"\x1f\x8b"

Format = Literal["mcap", "gzip", "raw"]


def detect_format(path: Path) -> Format:
    """``mcap``, ``gzip`` or ``raw``, from the file's first bytes (the name may lie).

    Raises:
        InputError: the file is missing, not a regular file (a directory, a FIFO or a device
            such as ``/dev/zero``, which would block or never end) or cannot be read.
    """
    check_regular(path)
    try:
        with path.open("rb") as f:
            head = f.read(len(MCAP_MAGIC))
    except FileNotFoundError as err:
        raise InputError(f"{path}: no such file") from err
    except OSError as err:
        raise InputError(f"{path}: cannot read: {err.strerror or err}") from err
    if head.startswith(MCAP_MAGIC):
        return "mcap"
    if head.startswith(GZIP_MAGIC):
        return "gzip"
    return "raw"


def check_regular(path: Path) -> None:
    """Refuse anything but a regular file (symbolic links followed) as an input.

    Raises:
        InputError: missing, a directory, a FIFO, a socket or a device.
    """
    try:
        mode = path.stat().st_mode
    except FileNotFoundError as err:
        raise InputError(f"{path}: no such file") from err
    except OSError as err:
        raise InputError(f"{path}: cannot read: {err.strerror or err}") from err
    if stat.S_ISREG(mode):
        return
    what = ("a directory" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode)
            else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "not a file")
    raise InputError(f"{path}: is {what}, not a recording (regular files only)")


@dataclass(frozen=True, slots=True)
class PartInfo:
    """What the head of a session part says about it (the recorder's ``groundstation``
    metadata record)."""

    session_id: str
    part: int
    station: str
    sidecar: str


def part_info(path: Path) -> PartInfo | None:
    """The session and part number of a recorder's MCAP, or ``None`` for any other file."""
    from groundstation.storage.mcapio import read_head_metadata  # mcap: only for MCAP parts

    meta = read_head_metadata(path).get("groundstation", {})
    session = meta.get("session_id", "")
    try:
        number = int(meta.get("part", ""))
    except ValueError:
        return None
    if not session or number < 1:
        return None
    return PartInfo(session, number, meta.get("station", ""), meta.get("sidecar", ""))


def _mcap_parts(path: Path, info: PartInfo) -> list[tuple[int, Path]]:
    """``(part number, file)`` of ``path`` and the later parts of its session, in order."""
    found: dict[int, Path] = {info.part: path}
    prefix = f"{info.station}_" if info.station else ""
    # Every part is named <station>_<its start time>[_n], never earlier than the session id.
    for cand in path.parent.iterdir():
        name = cand.name
        if (cand == path or not name.endswith(".mcap") or not name.startswith(prefix)
                or name[: -len(".mcap")] < info.session_id):
            continue
        refused = _outside(cand, path.parent)
        if refused:
            log.warning("session %s: %s %s: not read as one of its parts", info.session_id,
                        cand, refused)
            continue
        if not cand.is_file():
            continue
        try:
            if detect_format(cand) != "mcap":
                continue
        except InputError:
            continue  # vanished or unreadable meanwhile: not a part we can read
        other = part_info(cand)
        if other is None or other.session_id != info.session_id or other.part <= info.part:
            continue
        if other.part in found:
            log.warning("%s and %s both claim to be part %d of session %s; reading %s",
                        found[other.part].name, name, other.part, info.session_id,
                        found[other.part].name)
            continue
        found[other.part] = cand
    ordered = sorted(found.items())
    for (a, _), (b, _) in zip(ordered, ordered[1:], strict=False):
        if b != a + 1:
            log.warning("session %s: part(s) %d-%d missing in %s: their bytes are not read",
                        info.session_id, a + 1, b - 1, path.parent)
    return ordered


def _is_sidecar_name(name: str) -> bool:
    """A sidecar's name as the recorder writes it: a plain ``.ubx`` file name (no directory,
    no separator, not ``.`` or ``..``)."""
    return (name.endswith(".ubx") and "\0" not in name
            and not any(sep in name for sep in ("/", "\\", os.sep, os.altsep or "/")))


def _outside(cand: Path, directory: Path) -> str:
    """Why ``cand``, a name in ``directory``, may not be read as part of the recording there
    (``""``: it may): followed through symbolic links, it must stay in that directory."""
    if not cand.is_symlink():
        return ""
    try:
        real = cand.resolve()
        home = directory.resolve()
    except (OSError, RuntimeError) as err:  # a loop of links
        return f"is a symbolic link that cannot be followed ({err})"
    if real.parent != home:
        return f"is a symbolic link out of the recording's directory (to {real})"
    return ""


def _sidecar_of(mcap: Path, info: PartInfo, gz: bool) -> Path | None:
    """The sidecar of a part (as named in its metadata), plain or gzipped: a file name in the
    part's own directory, never a path (the metadata is the file's word, not the user's)."""
    if not info.sidecar:
        return None
    if not _is_sidecar_name(info.sidecar):
        log.warning("session %s: part %d (%s) names its sidecar %r, not a .ubx file name in "
                    "%s: refused, not read", info.session_id, info.part, mcap.name,
                    info.sidecar, mcap.parent)
        return None
    plain = mcap.parent / info.sidecar
    zipped = mcap.parent / (info.sidecar + ".gz")
    for cand in ((zipped, plain) if gz else (plain, zipped)):
        refused = _outside(cand, mcap.parent)
        if refused:
            log.warning("session %s: the sidecar of part %d, %s, %s: refused, not read",
                        info.session_id, info.part, cand, refused)
            continue
        if cand.is_file():
            return cand
    return None


def session_parts(path: Path, *, follow_parts: bool = True) -> tuple[Path, ...]:
    """The files to read for ``path``, in order (module docstring: the rule).

    Raises:
        InputError: ``path`` is missing or cannot be read.
    """
    fmt = detect_format(path)
    if not follow_parts:
        return (path,)
    if fmt == "mcap":
        info = part_info(path)
        if info is None:
            return (path,)
        parts = _mcap_parts(path, info)
        if info.part > 1:
            log.info("%s is part %d of session %s: reading from there on (parts before it "
                     "are not read)", path.name, info.part, info.session_id)
        return tuple(p for _, p in parts)
    name = path.name
    gz = name.endswith(".gz")
    base = name[: -len(".gz")] if gz else name
    if not base.endswith(".ubx"):
        return (path,)
    partner = path.with_name(base[: -len(".ubx")] + ".mcap")
    if not partner.is_file():
        return (path,)
    refused = _outside(partner, path.parent)
    if refused:
        log.warning("%s %s: refused, the session's later parts are not followed", partner,
                    refused)
        return (path,)
    if detect_format(partner) != "mcap":
        return (path,)
    info = part_info(partner)
    if info is None or info.sidecar != base:
        return (path,)
    out = [path]
    for number, mcap in _mcap_parts(partner, info)[1:]:
        other = part_info(mcap)
        side = _sidecar_of(mcap, other, gz) if other is not None else None
        if side is None:
            log.warning("session %s: the sidecar of part %d (%s) is missing: its bytes are "
                        "not read (they are in %s)", info.session_id, number,
                        other.sidecar if other else "?", mcap.name)
            continue
        out.append(side)
    return tuple(out)


class Recording:
    """A recording to read: one file, or the parts of one session, as one stream of chunks.

    Args:
        path: a ``.mcap``, ``.ubx``, ``.ubx.gz`` or raw log (format by content).
        follow_parts: read the session's later parts too (module docstring).

    Raises:
        InputError: ``path`` is missing or cannot be read.
    """

    def __init__(self, path: str | Path, *, follow_parts: bool = True) -> None:
        self.path = Path(path)
        self.format: Format = detect_format(self.path)
        self.parts: tuple[Path, ...] = session_parts(self.path, follow_parts=follow_parts)
        if len(self.parts) > 1:
            log.info("%s: reading %d parts of its session: %s", self.path, len(self.parts),
                     ", ".join(p.name for p in self.parts))
        self.size_bytes = sum(_size(p) for p in self.parts)
        """Bytes on disk of all parts (compressed), for progress."""
        self._done_bytes = 0
        self._current: BinaryIO | None = None
        self.skipped: list[Skipped] = []
        """Damaged stretches of MCAP parts read past by :meth:`chunks` (each one also logged
        as a warning naming its byte range and the time span lost)."""
        self.orphan_messages = 0
        """Messages whose channel was defined only in a skipped stretch (not read)."""

    @property
    def bytes_read(self) -> int:
        """Bytes on disk consumed so far (compressed), against :attr:`size_bytes`."""
        f = self._current
        if f is None or f.closed:
            return self._done_bytes
        return self._done_bytes + f.tell()

    @property
    def progress(self) -> float:
        """Fraction of :attr:`size_bytes` read, 0 to 1."""
        return min(self.bytes_read / self.size_bytes, 1.0) if self.size_bytes else 1.0

    def chunks(
        self, chunk_bytes: int = CHUNK_BYTES, *,
        also: Mapping[str, Callable[[McapMessage], None]] | None = None,
    ) -> Iterator[tuple[bytes, int]]:
        """Yield ``(chunk, t_host_ns)`` from every part in order.

        For MCAP, ``t_host_ns`` is each ``/ubx/raw`` message's ``log_time`` (the host time of
        reception) and chunks are the recorded ones; for other files it is 0 (they hold no
        reception times) and chunks are ``chunk_bytes`` long. ``also`` hands an MCAP's messages
        of other topics, read in the same pass, to their topic's callback
        (:func:`~groundstation.storage.mcapio.iter_raw_chunks`); other files have none.

        Raises:
            InputError: a part cannot be opened or read, or its compressed data is corrupt
                (a torn gzip ends quietly instead, like an unfinished MCAP, after what it
                holds).
        """
        self._done_bytes = 0
        self.skipped = []
        self.orphan_messages = 0
        for part in self.parts:
            yield from self._part_chunks(part, chunk_bytes, also)
            self._done_bytes += _size(part)

    def _part_chunks(
        self, part: Path, chunk_bytes: int,
        also: Mapping[str, Callable[[McapMessage], None]] | None = None,
    ) -> Iterator[tuple[bytes, int]]:
        fmt = detect_format(part)
        try:
            with part.open("rb") as f:
                self._current = f
                if fmt == "mcap":
                    # imported here: the mcap library is not needed for a .ubx (rinex, inspect)
                    from groundstation.storage.mcapio import ReadReport, iter_raw_chunks

                    report = ReadReport()
                    try:
                        yield from iter_raw_chunks(f, report=report, also=also)
                    finally:
                        self.skipped += report.skipped
                        self.orphan_messages += report.orphan_messages
                elif fmt == "gzip":
                    with gzip.GzipFile(fileobj=f, mode="rb") as gz:
                        try:
                            # read1: what one read decompresses, so a torn end loses nothing
                            # before it
                            while chunk := gz.read1(chunk_bytes):
                                yield chunk, 0
                        except EOFError as err:  # cut short (a copy in progress, a full disk)
                            log.warning("%s: compressed stream ends early (%s): read up to "
                                        "there", part, err)
                else:
                    while chunk := f.read(chunk_bytes):
                        yield chunk, 0
        except gzip.BadGzipFile as err:
            raise InputError(f"{part}: corrupt gzip data: {err}") from err
        except zlib.error as err:
            raise InputError(f"{part}: corrupt gzip data (after {self.bytes_read} compressed "
                             f"bytes): {err}") from err
        except OSError as err:
            raise InputError(f"{part}: read failed: {err.strerror or err}") from err
        finally:
            self._current = None


def iter_chunks(
    path: str | Path, chunk_bytes: int = CHUNK_BYTES, *, follow_parts: bool = True
) -> Iterator[tuple[bytes, int]]:
    """``(chunk, t_host_ns)`` of a recording and its session's later parts
    (:meth:`Recording.chunks`)."""
    yield from Recording(path, follow_parts=follow_parts).chunks(chunk_bytes)


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0
