"""Photo files: the capture time a camera wrote in a JPEG's EXIF, read by a bounded parser of
its own (a crafted photo must not hang the solver), and copies of the photos with their position
in the GPS tags (exiv2 through ``pyexiv2``: position and accuracy, EXIF and XMP, the rest of the
metadata kept); :func:`make_jpeg` makes test and demo photos (EXIF by the ``exif`` library).

The edge of the photo work: :func:`read_photo` and :func:`scan_photos` give :class:`Photo`
values to the pairing (:mod:`groundstation.solve.photos`); :func:`write_gps_copy` is called by
the exports.
"""

from __future__ import annotations

import datetime as dt
import logging
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Literal

from groundstation import gpstime
from groundstation.errors import InputError

log = logging.getLogger(__name__)

JPEG_SUFFIXES = (".jpg", ".jpeg", ".jpe")


@dataclass(frozen=True, slots=True)
class Photo:
    """One photo's capture time as the camera wrote it.

    Attributes:
        name: file name.
        path: full path.
        exif_second_ns: ``DateTimeOriginal`` as UNIX ns, read as UTC (whole seconds).
        subsec_ns: ``SubSecTimeOriginal`` in ns, or ``None`` when absent.
        utc_offset_s: ``OffsetTimeOriginal`` in seconds east of UTC, or ``None``.
        time_tag: which EXIF tag gave the time (``DateTimeOriginal`` or ``DateTime``).
        error: why the photo has no usable time (then the times are 0).
    """

    name: str
    path: str
    exif_second_ns: int
    subsec_ns: int | None = None
    utc_offset_s: int | None = None
    time_tag: str = "DateTimeOriginal"
    error: str = ""

    @property
    def usable(self) -> bool:
        return not self.error

    @property
    def utc_second_ns(self) -> int:
        """The EXIF second on the UTC scale when the camera stated its zone, else as written."""
        return self.exif_second_ns - (self.utc_offset_s or 0) * gpstime.NS_PER_S


def natural_key(name: str) -> tuple[tuple[int, int | str], ...]:
    """Sort key that orders ``IMG_9.JPG`` before ``IMG_10.JPG``."""
    return tuple(
        (0, int(part)) if part.isdigit() else (1, part.lower())
        for part in re.split(r"(\d+)", name)
        if part
    )


def parse_exif_datetime(text: str) -> dt.datetime:
    """``YYYY:MM:DD HH:MM:SS`` (EXIF) as a naive datetime."""
    return dt.datetime.strptime(text.strip().rstrip("\x00"), "%Y:%m:%d %H:%M:%S")


def parse_subsec(text: str) -> int | None:
    """``SubSecTimeOriginal`` (decimal fraction digits) as ns; ``None`` if empty or invalid."""
    digits = text.strip().rstrip("\x00").strip()
    if not digits.isdigit():
        return None
    return int((digits + "000000000")[:9])


def parse_utc_offset(text: str) -> int | None:
    """``OffsetTimeOriginal`` (``+02:00``) as seconds east of UTC."""
    m = re.fullmatch(r"\s*([+-])(\d\d):(\d\d)\s*\x00*", text)
    if not m:
        return None
    s = int(m.group(2)) * 3600 + int(m.group(3)) * 60
    return s if m.group(1) == "+" else -s


def _unix_ns(naive: dt.datetime) -> int:
    return int(naive.replace(tzinfo=dt.UTC).timestamp()) * gpstime.NS_PER_S


EXIF_MAX_SEGMENTS = 64
"""JPEG segments looked at for the EXIF block before giving up (it normally comes first); only
their 4-byte headers are read, and the EXIF body itself (at most 64 KiB)."""
EXIF_MAX_IFDS = 16
"""IFDs visited at most in one photo's EXIF (each at most once)."""
EXIF_MAX_ENTRIES = 2000
"""Entries at most in one IFD. With :data:`EXIF_MAX_IFDS` this bounds the work of any photo,
crafted or not, to 32 000 fixed-size reads: milliseconds, whatever the file. Up to 2026-11-29
a wall-clock budget of 0.5 s came on top; on a busy machine (a solve beside other work, a test
suite beside a benchmark) a process paused for longer than that lost a good photo with "EXIF
parsing over its budget", 1 of 300 in one run of the photo tests. The count bounds the same
hang without depending on what else runs."""

_TAG_DATETIME, _TAG_EXIF_IFD, _TAG_GPS_IFD = 0x0132, 0x8769, 0x8825
_TAG_ORIGINAL, _TAG_OFFSET_ORIGINAL, _TAG_SUBSEC_ORIGINAL = 0x9003, 0x9011, 0x9291
_TAG_INTEROP_IFD = 0xA005


class ExifError(ValueError):
    """A photo's EXIF block cannot be used (damaged, looping, too large)."""


def _tiff_reader(tiff: bytes) -> tuple[Literal["little", "big"], Callable[[int, int], int]]:
    """A TIFF block's byte order and a bounds-checked reader of its unsigned integers.

    Raises:
        ExifError: not a TIFF header.
    """
    if len(tiff) < 8 or tiff[:4] not in (b"II*\x00", b"MM\x00*"):
        raise ExifError("bad TIFF header in EXIF")
    order: Literal["little", "big"] = "little" if tiff[:2] == b"II" else "big"

    def u(off: int, n: int) -> int:
        if off < 0 or off + n > len(tiff):
            raise ExifError(f"EXIF offset {off} outside the {len(tiff)}-byte block")
        return int.from_bytes(tiff[off : off + n], order)

    return order, u


def _exif_block(f: BinaryIO) -> bytes | None:
    """The TIFF data of a JPEG's ``Exif`` APP1 segment (``None``: the JPEG has none), found by
    walking the segment headers (seeking over their bodies).

    Raises:
        ExifError: not a JPEG, a damaged segment, or no EXIF within the first
            :data:`EXIF_MAX_SEGMENTS` segments.
    """
    if f.read(2) != b"\xff\xd8":
        raise ExifError("not a JPEG")
    for _ in range(EXIF_MAX_SEGMENTS):
        head = f.read(2)
        while head[:1] == b"\xff" and head[1:2] == b"\xff":  # fill bytes
            head = head[1:] + f.read(1)
        if len(head) < 2:
            return None  # ends before any image data: no EXIF
        if head[0] != 0xFF:
            raise ExifError(f"damaged JPEG segment at byte {f.tell() - 2}")
        marker = head[1]
        if marker in (0xD9, 0xDA):  # end of image, start of scan: no EXIF after this
            return None
        if 0xD0 <= marker <= 0xD7 or marker == 0x01:  # standalone markers
            continue
        raw = f.read(2)
        length = int.from_bytes(raw, "big")
        if len(raw) < 2 or length < 2:
            raise ExifError(f"damaged JPEG segment length at byte {f.tell() - 2}")
        if marker == 0xE1:
            body = f.read(length - 2)
            if len(body) < length - 2:
                raise ExifError("EXIF segment cut short")
            if body.startswith(b"Exif\x00\x00"):
                return body[6:]
            continue
        f.seek(length - 2, 1)
    raise ExifError(f"no EXIF within the first {EXIF_MAX_SEGMENTS} JPEG segments")


def _exif_tags(tiff: bytes) -> dict[int, str]:
    """The ASCII tags of IFD0 and the Exif IFD, with every IFD pointer checked: in bounds,
    visited once (a looping chain is an error), at most :data:`EXIF_MAX_IFDS` IFDs of at most
    :data:`EXIF_MAX_ENTRIES` entries.

    Raises:
        ExifError: damaged, looping or too large.
    """
    order, u = _tiff_reader(tiff)

    tags: dict[int, str] = {}
    seen: set[int] = set()
    todo: list[tuple[int, bool]] = [(u(4, 4), True)]  # (offset, follow the next-IFD chain)
    while todo:
        off, chain = todo.pop()
        if off == 0:
            continue
        if off in seen:
            raise ExifError(f"looping EXIF IFD chain (offset {off} visited twice)")
        if len(seen) >= EXIF_MAX_IFDS:
            raise ExifError(f"more than {EXIF_MAX_IFDS} EXIF IFDs")
        seen.add(off)
        count = u(off, 2)
        if count > EXIF_MAX_ENTRIES:
            raise ExifError(f"EXIF IFD with {count} entries")
        for k in range(count):
            e = off + 2 + 12 * k
            tag, kind, n = u(e, 2), u(e + 2, 2), u(e + 4, 4)
            if tag in (_TAG_EXIF_IFD, _TAG_GPS_IFD, _TAG_INTEROP_IFD):
                todo.append((u(e + 8, 4), False))
            elif kind == 2 and tag in (_TAG_DATETIME, _TAG_ORIGINAL, _TAG_OFFSET_ORIGINAL,
                                       _TAG_SUBSEC_ORIGINAL):
                start = e + 8 if n <= 4 else u(e + 8, 4)
                if n > 256 or start + n > len(tiff):
                    raise ExifError(f"EXIF tag 0x{tag:04x} runs outside the block")
                tags.setdefault(tag, tiff[start : start + n].split(b"\x00")[0]
                                .decode("ascii", "replace"))
        if chain:
            todo.append((u(off + 2 + 12 * count, 4), True))
    return tags


def read_exif_times(path: Path) -> dict[int, str]:
    """The capture-time tags of one JPEG, read within a size and work budget.

    Raises:
        OSError: the file cannot be read.
        ExifError: no usable EXIF block (damaged, looping, too large).
    """
    with path.open("rb") as f:
        tiff = _exif_block(f)
    if tiff is None:
        return {}
    return _exif_tags(tiff)


def read_photo(path: str | Path) -> Photo:
    """The EXIF capture time of one JPEG (never raises for bad photos: see ``Photo.error``).

    The EXIF block is parsed here, within a budget (:data:`EXIF_MAX_SEGMENTS` segment headers,
    the EXIF body of at most 64 KiB, at most :data:`EXIF_MAX_IFDS` IFDs visited once each): a
    damaged or crafted photo (a looping IFD chain) is skipped with its reason, never a hang.
    """
    p = Path(path)
    try:
        tags = read_exif_times(p)
    except OSError as err:
        return Photo(p.name, str(p), 0, error=f"cannot read: {err.strerror or err}")
    except ExifError as err:
        return Photo(p.name, str(p), 0, error=f"no readable EXIF: {err}")
    if not tags:
        return Photo(p.name, str(p), 0, error="no EXIF")
    tag = "DateTimeOriginal"
    text = tags.get(_TAG_ORIGINAL, "")
    if not text:
        tag, text = "DateTime", tags.get(_TAG_DATETIME, "")
    if not text:
        return Photo(p.name, str(p), 0, error="no DateTimeOriginal")
    try:
        second = _unix_ns(parse_exif_datetime(text))
    except ValueError:
        return Photo(p.name, str(p), 0, error=f"bad {tag} {text!r}")
    sub = tags.get(_TAG_SUBSEC_ORIGINAL, "")
    off = tags.get(_TAG_OFFSET_ORIGINAL, "")
    return Photo(
        p.name, str(p), second,
        parse_subsec(sub) if sub else None,
        parse_utc_offset(off) if off else None,
        tag,
    )


def scan_photos(directory: str | Path) -> list[Photo]:
    """Every JPEG in ``directory`` (not recursive), in natural file-name order."""
    d = Path(directory)
    if not d.is_dir():
        raise InputError(f"{d}: not a directory")
    files = sorted(
        (p for p in d.iterdir() if p.suffix.lower() in JPEG_SUFFIXES and p.is_file()),
        key=lambda p: natural_key(p.name),
    )
    return [read_photo(p) for p in files]


# -- writing ------------------------------------------------------------------------------------


def make_jpeg(
    datetime_original: dt.datetime | None,
    *,
    subsec: str | None = None,
    offset_time: str | None = None,
) -> bytes:
    """A valid 8×8 grey baseline JPEG with the given EXIF capture time (tests and the demo).

    The image is hand-made (one DC-only block, one-symbol Huffman tables) so no imaging library
    is needed; the EXIF block is written by the ``exif`` library like any camera's.
    """
    from exif import Image

    dqt = b"\xff\xdb\x00\x43\x00" + bytes([1] * 64)
    sof = b"\xff\xc0\x00\x0b\x08\x00\x08\x00\x08\x01\x01\x11\x00"
    # DC table 0 and AC table 0: one code of length 1 each (DC category 0, AC end of block).
    dht = (
        b"\xff\xc4\x00\x14\x00" + bytes([1] + [0] * 15) + b"\x00"
        + b"\xff\xc4\x00\x14\x10" + bytes([1] + [0] * 15) + b"\x00"
    )
    sos = b"\xff\xda\x00\x08\x01\x01\x00\x00\x3f\x00"
    # DC diff 0 (code '0') then EOB (code '0'), padded with ones: a mid-grey block.
    scan = b"\x3f"
    app0 = b"\xff\xe0\x00\x10JFIF\x00\x01\x01\x00\x00\x01\x00\x01\x00\x00"
    jpeg = b"\xff\xd8" + app0 + dqt + sof + dht + sos + scan + b"\xff\xd9"
    if datetime_original is None:
        return jpeg
    img = Image(jpeg)
    img.datetime_original = datetime_original.strftime("%Y:%m:%d %H:%M:%S")
    if subsec is not None:
        img.subsec_time_original = subsec
    if offset_time is not None:
        img.offset_time_original = offset_time
    return bytes(img.get_file())


def _dms(value: float) -> str:
    """Degrees as EXIF rationals: ``53/1 16/1 496192/10000``."""
    v = abs(value)
    d = math.floor(v)
    m = math.floor((v - d) * 60)
    s = (v - d - m / 60) * 3600
    return f"{d}/1 {m}/1 {round(s * 1_000_000)}/1000000"


PIX4D_CAMERA_NS = "http://pix4d.com/camera/1.0/"
"""The XMP namespace (prefix ``Camera``) whose ``GPSXYAccuracy`` and ``GPSZAccuracy`` Pix4D
reads for each image's position accuracy."""


def write_gps_copy(src: Path, dst: Path, lat_deg: float, lon_deg: float, h_m: float,
                   sd_h_m: float = math.nan, sd_v_m: float = math.nan) -> bool:
    """Copy a photo to ``dst`` with its position in the EXIF GPS tags (WGS-84) and its
    accuracy where photogrammetry tools look for it (EXIF ``GPSHPositioningError``, XMP
    ``Camera:GPSXYAccuracy`` / ``Camera:GPSZAccuracy``); ``src`` is only read. Written by
    exiv2 (``pyexiv2``), which keeps the rest of the metadata (maker notes, thumbnail, XMP)
    as it was.

    Returns:
        Whether the copy was written; a photo whose metadata cannot take the tags (damaged)
        is skipped with one warning line naming it.

    Raises:
        InputError: ``dst`` is ``src``.
    """
    import shutil

    import pyexiv2

    if src.resolve() == dst.resolve():
        raise InputError(f"{dst}: refusing to overwrite the original photo")
    exif = {
        "Exif.GPSInfo.GPSVersionID": "2 3 0 0",
        "Exif.GPSInfo.GPSLatitudeRef": "N" if lat_deg >= 0 else "S",
        "Exif.GPSInfo.GPSLatitude": _dms(lat_deg),
        "Exif.GPSInfo.GPSLongitudeRef": "E" if lon_deg >= 0 else "W",
        "Exif.GPSInfo.GPSLongitude": _dms(lon_deg),
        "Exif.GPSInfo.GPSAltitudeRef": "0" if h_m >= 0 else "1",
        "Exif.GPSInfo.GPSAltitude": f"{round(abs(h_m) * 1000)}/1000",
        "Exif.GPSInfo.GPSMapDatum": "WGS-84",
    }
    xmp = {}
    if math.isfinite(sd_h_m):
        exif["Exif.GPSInfo.GPSHPositioningError"] = f"{round(sd_h_m * 1000)}/1000"
        xmp["Xmp.Camera.GPSXYAccuracy"] = f"{sd_h_m:.3f}"
    if math.isfinite(sd_v_m):
        xmp["Xmp.Camera.GPSZAccuracy"] = f"{sd_v_m:.3f}"
    part = dst.with_name(f".{dst.name}.part")
    try:
        shutil.copyfile(src, part)
        pyexiv2.registerNs(PIX4D_CAMERA_NS, "Camera")
        with pyexiv2.Image(str(part)) as img:
            img.modify_exif(exif)
            if xmp:
                img.modify_xmp(xmp)
    except (RuntimeError, ValueError, KeyError) as err:  # exiv2's errors on damaged metadata
        part.unlink(missing_ok=True)
        log.warning("%s: no copy with GPS tags written: %s", src.name, err)
        return False
    part.replace(dst)
    return True
