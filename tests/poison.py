"""Hostile inputs shared by the tests: bus payloads a broken peer may send (the views and the
solver must drop them) and a photo crafted to hang an EXIF parser."""

from __future__ import annotations

import struct

POISON: list[tuple[str, bytes]] = [
    ("groundstation/st/timemark",
     b'{"schema":1,"type":"timemark","index":7,"count":7,"falling_t_gps_ns":1e25}'),
    ("groundstation/st/timemark",
     b'{"schema":1,"type":"timemark","index":8,"falling_t_gps_ns":10000000000000000000000000}'),
    ("groundstation/st/event",
     b'{"schema":1,"type":"event","kind":"x","t_host_ns":1e30,"message":"m","data":{}}'),
    ("groundstation/st/event", b'{"schema":1,"type":"event","kind":3,"t_host_ns":0}'),
    ("groundstation/st/status", b'{"schema":1,"type":"status","link":"fast","sats":7}'),
    ("groundstation/st/status", b'{"schema":1,"type":"status","link":{"epoch_interval_s":-1}}'),
    ("groundstation/st/status", b'{"schema":1,"type":"timemark","index":1}'),  # wrong key
    ("groundstation/st/session", b'{"schema":1,"type":"session","files":[1,2]}'),
    ("groundstation/st/status", b"\xff\xfe not json"),
    ("groundstation/st/status", b"[1,2,3]"),
    ("groundstation/st/status", b'{"type":"status","a":' * 40 + b"1" + b"}" * 40),
]
"""(key, payload): each breaks a rule of :mod:`groundstation.messages`."""


def looping_exif_jpeg(size: int = 215) -> bytes:
    """A JPEG whose EXIF IFD0 names itself as the next IFD (the ``exif`` library loops for
    ever on it, growing memory); padded with a comment segment to ``size`` bytes."""
    text = b"2024:01:02 03:04:05\x00"
    ifd = (struct.pack("<H", 1) + struct.pack("<HHII", 0x0132, 2, len(text), 26)
           + struct.pack("<I", 8))  # next IFD: itself
    tiff = b"II*\x00" + struct.pack("<I", 8) + ifd + text
    app1 = b"Exif\x00\x00" + tiff
    head = b"\xff\xd8" + b"\xff\xe1" + struct.pack(">H", len(app1) + 2) + app1
    pad = size - len(head) - 2 - 4
    return head + b"\xff\xfe" + struct.pack(">H", pad + 2) + b"\x00" * pad + b"\xff\xd9"
