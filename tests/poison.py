"""Bus payloads a hostile or broken peer may send (the views and the solver must drop them)."""

from __future__ import annotations

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
