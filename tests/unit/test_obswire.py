"""The compact ``obs`` payloads: every epoch and subframe of a simulated stream comes back as
the live engine needs it (times, measurements, loss-of-lock bits, validity, words), the size
is what docs/zenoh.md says, and what is not ours is refused."""

from __future__ import annotations

import pytest

from groundstation.live import obswire
from groundstation.live.rtk import measurements
from groundstation.records import RawEpoch, Subframe
from groundstation.sim.stream import SimConfig, simulate


def _items() -> list[RawEpoch | Subframe]:
    return measurements(simulate(SimConfig(duration_s=40.0, seed=5, with_base=False)).rover_bytes)


def test_every_epoch_and_subframe_round_trips() -> None:
    items = _items()
    epochs = [r for r in items if isinstance(r, RawEpoch)]
    frames = [r for r in items if isinstance(r, Subframe)]
    assert len(epochs) >= 190 and frames
    for e in epochs:
        payload = obswire.encode_epoch(e)
        assert len(payload) == 12 + 25 * len(e.sats)
        back = obswire.decode(payload)
        assert isinstance(back, RawEpoch)
        assert (back.t_gps_ns, back.source, back.clock_reset) == (
            e.t_gps_ns, e.source, e.clock_reset)
        for a, b in zip(e.sats, back.sats, strict=True):
            assert (a.gnss, a.sv, a.pseudorange_m, a.carrier_phase_cyc, a.cno_dbhz, a.lli,
                    a.slip, a.half_cycle_unresolved, a.pr_valid, a.cp_valid) == (
                b.gnss, b.sv, b.pseudorange_m, b.carrier_phase_cyc, b.cno_dbhz, b.lli,
                b.slip, b.half_cycle_unresolved, b.pr_valid, b.cp_valid)
            assert b.doppler_hz == pytest.approx(a.doppler_hz, abs=1e-3)  # float32
    for f in frames:
        back = obswire.decode(obswire.encode_subframe(f))
        assert isinstance(back, Subframe)
        assert (back.gnss, back.sv, back.words, back.source) == (f.gnss, f.sv, f.words, f.source)
        assert back.data_words() == f.data_words()


@pytest.mark.parametrize(("payload", "said"), [
    (b"", "not an obs message"),
    (b"E\x02" + bytes(10), "not an obs message of version 1"),
    (b"E\x01" + bytes(5), "epoch cut short"),
    (b"E\x01" + bytes(8) + b"\x02\x00" + bytes(25), "epoch of 2 measurements is 37 bytes"),
    (b"F\x01\x00\x05\x00\x0a" + bytes(8), "subframe of 10 words is 14 bytes"),
    (b"X\x01", "unknown obs message kind"),
])
def test_what_is_not_ours_is_refused(payload: bytes, said: str) -> None:
    with pytest.raises(obswire.ObsWireError, match=said):
        obswire.decode(payload)
