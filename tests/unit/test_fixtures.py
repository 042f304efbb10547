"""The checked-in damaged fixtures (tests/data/) read as a correct reader must read them.

Each file is read through the one recording reader (:class:`~groundstation.storage.reading.
Recording`: raw ``.ubx``, torn ``.mcap``, cut ``.ubx.gz``), framed by
:class:`~groundstation.ubx.framer.UbxFramer` and decoded by
:class:`~groundstation.ubx.decode.Decoder` under both policies, and the result is compared with
``manifest.json``, which the generator (tests/data/make_fixtures.py) wrote from what it did to
the bytes, not from this framer.
"""

from __future__ import annotations

import hashlib
import json
from collections import Counter
from pathlib import Path
from typing import Any

import pytest

from groundstation.errors import DecodeError
from groundstation.records import Frame, UndecodedFrame
from groundstation.storage.reading import Recording
from groundstation.ubx.decode import Decoder, message_name
from groundstation.ubx.framer import UbxFramer

DATA = Path(__file__).resolve().parents[1] / "data"
MANIFEST: dict[str, dict[str, Any]] = json.loads((DATA / "manifest.json").read_text())


def _stream(name: str) -> bytes:
    return b"".join(chunk for chunk, _ in Recording(DATA / name, follow_parts=False).chunks())


def _frame(data: bytes, piece: int) -> tuple[list[Frame], UbxFramer]:
    """Frames of ``data`` fed in pieces of ``piece`` bytes (the result must not depend on it)."""
    framer = UbxFramer()
    frames: list[Frame] = []
    for i in range(0, len(data), piece):
        frames += framer.feed(data[i : i + piece], 0)
    frames += framer.flush()
    return frames, framer


def test_every_fixture_is_in_the_manifest() -> None:
    on_disk = {p.name for p in DATA.iterdir() if p.suffix in (".ubx", ".mcap", ".gz")}
    assert on_disk == set(MANIFEST)
    for name in on_disk:
        assert (DATA / name).stat().st_size < 50_000, name


@pytest.mark.parametrize("piece", [1 << 16, 61])
@pytest.mark.parametrize("name", sorted(MANIFEST))
def test_lenient_recovers_every_intact_frame_and_counts_the_damage(name: str, piece: int) -> None:
    want = MANIFEST[name]
    data = _stream(name)
    assert len(data) == want["stream_bytes"]
    frames, framer = _frame(data, piece)
    st = framer.stats
    assert hashlib.sha256(b"".join(f.raw for f in frames)).hexdigest() == want["intact_sha256"]
    assert dict(Counter(message_name(f.cls, f.id) for f in frames)) == want["frames"]
    got = {k: getattr(st, k) for k in ("bad_checksum", "too_long", "truncated", "damaged_frames",
                                       "garbage_bytes", "nmea_sentences", "rtcm3_frames")}
    assert got == {k: want[k] for k in got}
    assert st.pending_bytes == 0
    assert st.bytes_in == st.frame_bytes + st.garbage_bytes + st.nmea_bytes + st.rtcm3_bytes

    decoder = Decoder(raise_on_error=False)
    records = [decoder.decode(f) for f in frames]
    undecoded = Counter(message_name(r.frame.cls, r.frame.id)
                        for r in records if isinstance(r, UndecodedFrame))
    assert dict(undecoded) == want["undecodable"]
    assert decoder.stats.decoded == want["decoded"]
    assert decoder.stats.undecodable_by_type == want["undecodable"]
    # an undecodable frame keeps its bytes
    assert all(r.frame.raw for r in records if isinstance(r, UndecodedFrame))


@pytest.mark.parametrize("name", sorted(MANIFEST))
def test_strict_raises_on_undecodable_and_counts_the_same_damage(name: str) -> None:
    want = MANIFEST[name]
    frames, framer = _frame(_stream(name), 1 << 16)
    st = framer.stats
    assert (st.bad_checksum, st.too_long, st.truncated) == (
        want["bad_checksum"], want["too_long"], want["truncated"])
    decoder = Decoder(raise_on_error=True)
    if want["undecodable"]:
        with pytest.raises(DecodeError, match=next(iter(want["undecodable"]))):
            for f in frames:
                decoder.decode(f)
    else:
        for f in frames:
            decoder.decode(f)
        assert decoder.stats.decoded == want["decoded"]
