"""Reading recordings as byte chunks: ``.ubx``, ``.ubx.gz``, raw logs, and MCAP ``/ubx/raw``.

Every offline tool goes through :func:`iter_chunks`, then the same framer and decoder as the live
daemon, so a file gives the same frames whether it is replayed, converted or inspected.
"""

from __future__ import annotations

import gzip
from collections.abc import Iterator
from pathlib import Path

from groundstation.errors import InputError

CHUNK_BYTES = 1 << 16
MCAP_MAGIC = b"\x89MCAP0\r\n"
GZIP_MAGIC = b"\x1f\x8b"


def detect_format(path: Path) -> str:
    """``mcap``, ``gzip`` or ``raw``, from the file's first bytes (the name may lie)."""
    try:
        with path.open("rb") as f:
            head = f.read(8)
    except FileNotFoundError as err:
        raise InputError(f"{path}: no such file") from err
    except OSError as err:
        raise InputError(f"{path}: cannot read: {err.strerror or err}") from err
    if head.startswith(MCAP_MAGIC):
        return "mcap"
    if head.startswith(GZIP_MAGIC):
        return "gzip"
    return "raw"


def iter_chunks(path: str | Path, chunk_bytes: int = CHUNK_BYTES) -> Iterator[tuple[bytes, int]]:
    """Yield ``(chunk, t_host_ns)`` from a recording.

    For ``.ubx``/``.ubx.gz``/raw logs ``t_host_ns`` is 0 (the file has no reception times);
    for MCAP it is each ``/ubx/raw`` message's ``log_time``. An unfinished MCAP yields what it
    holds up to its last complete chunk.
    """
    p = Path(path)
    fmt = detect_format(p)
    if fmt == "mcap":
        from groundstation.storage import mcapio  # the one module that owns the mcap library

        yield from mcapio.iter_raw_chunks(p)
        return
    try:
        if fmt == "gzip":
            with gzip.open(p, "rb") as gz:
                while chunk := gz.read(chunk_bytes):
                    yield chunk, 0
        else:
            with p.open("rb") as f:
                while chunk := f.read(chunk_bytes):
                    yield chunk, 0
    except (OSError, EOFError) as err:
        raise InputError(f"{p}: read failed: {err}") from err


def file_size(path: str | Path) -> int:
    """Size on disk, for progress display."""
    return Path(path).stat().st_size
