"""The "no valid frames" alert: bytes that arrive without one frame checking out."""

from __future__ import annotations

import pytest

from groundstation.config import load_settings
from groundstation.errors import ConfigError
from groundstation.gpstime import NS_PER_S
from groundstation.live.monitor import Monitor, MonitorThresholds
from groundstation.records import Event, PipelineStatus

HOST0 = 1_700_000_000 * NS_PER_S


def pipeline(t: int, bytes_in: int, frames: int, nmea: int = 0) -> PipelineStatus:
    return PipelineStatus(t, "serial:/dev/x", True, bytes_in, 0, frames, 0, 0, 0, 0, {}, {},
                          nmea_sentences=nmea)


def feed(m: Monitor, seconds: float, *, frames_per_s: int = 0, nmea_per_s: int = 0,
         t0: int = HOST0, bytes0: int = 0, frames0: int = 0, nmea0: int = 0,
         ) -> tuple[list[Event], int, int, int, int]:
    """1152 bytes every 100 ms (a 115200-baud line) with a pipeline status every second."""
    events: list[Event] = []
    t, b, f, n = t0, bytes0, frames0, nmea0
    for step in range(int(seconds * 10)):
        t += 100_000_000
        b += 1152
        m.on_bytes(1152, t)
        if step % 10 == 9:
            f += frames_per_s
            n += nmea_per_s
            events += m.observe(pipeline(t, b, f, n), t)
        events += m.tick(t)[1]
    return events, t, b, f, n


def alerts(events: list[Event], kind: str) -> list[Event]:
    return [e for e in events if e.kind == kind and e.data.get("alert") == "no_frames"]


def test_random_bytes_raise_no_frames_naming_baud_or_noise_and_frames_clear_it() -> None:
    m = Monitor("t", MonitorThresholds(no_frames_s=4.0))
    events, t, b, f, n = feed(m, 3.5)
    assert not alerts(events, "alert.raised")
    events, t, b, f, n = feed(m, 1.5, t0=t, bytes0=b)
    (raised,) = alerts(events, "alert.raised")
    assert raised.message.startswith("no valid frames for 4 s although ")
    assert raised.message.endswith(
        "likely cause: wrong baud rate (bytes arrive but no frame checks out), or noise on "
        "the line"
    )
    assert raised.data["likely_cause"] == "baud_or_noise"
    assert any("no valid frames" in a for a in m.status(t).alerts)
    # frames come again (the operator fixed the baud rate): cleared once they have kept
    # decoding for no_frames_s (the hold), not at the first one
    events, t, b, f, n = feed(m, 3.0, frames_per_s=20, t0=t, bytes0=b, frames0=f)
    assert not alerts(events, "alert.cleared")
    events, t, b, f, n = feed(m, 3.0, frames_per_s=20, t0=t, bytes0=b, frames0=f)
    (cleared,) = alerts(events, "alert.cleared")
    assert cleared.message.startswith("OK again (was: no valid frames")
    assert not any("no valid frames" in a for a in m.status(t).alerts)


def test_a_stray_frame_amid_noise_does_not_clear_it() -> None:
    """Noise (the framer's garbage grows with the bytes) with one frame that checks out
    every 2 s, for longer than the hold: raised once, never cleared."""
    m = Monitor("t", MonitorThresholds(no_frames_s=1.5))
    events: list[Event] = []
    t, b, frames = HOST0, 0, 0
    for step in range(200):  # 20 s
        t += 100_000_000
        b += 1152
        m.on_bytes(1152, t)
        if step % 10 == 9:
            frames += step % 20 == 19  # a stray frame every other second
            events += m.observe(PipelineStatus(t, "serial:/dev/x", True, b, 0, frames,
                                               b - 24 * frames, 0, 0, 0, {}, {}), t)
        events += m.tick(t)[1]
    assert len(alerts(events, "alert.raised")) == 1
    assert not alerts(events, "alert.cleared")


def test_nmea_only_names_the_receiver_configuration() -> None:
    m = Monitor("t", MonitorThresholds(no_frames_s=2.0))
    events, *_ = feed(m, 4.0, nmea_per_s=10)
    (raised,) = alerts(events, "alert.raised")
    assert "NMEA only" in raised.message and "groundstation configure" in raised.message


def test_a_healthy_stream_never_raises_it() -> None:
    m = Monitor("t", MonitorThresholds(no_frames_s=1.0))
    events, *_ = feed(m, 30.0, frames_per_s=15)
    assert not alerts(events, "alert.raised")


def test_silence_is_no_data_not_no_frames() -> None:
    m = Monitor("t", MonitorThresholds(no_frames_s=1.0, no_data_s=2.0))
    t = HOST0
    m.on_bytes(10, t)
    events: list[Event] = []
    for _ in range(50):
        t += 100_000_000
        events += m.tick(t)[1]
    assert not alerts(events, "alert.raised")
    assert [e.data["alert"] for e in events if e.kind == "alert.raised"] == ["no_data"]


def test_threshold_is_a_validated_setting() -> None:
    s = load_settings(environ={}, overrides={"source": {"port": "/dev/x"},
                                             "monitor": {"no_frames_s": 7.5}})
    assert s.monitor.no_frames_s == 7.5
    with pytest.raises(ConfigError, match="monitor.no_frames_s"):
        load_settings(environ={}, overrides={"source": {"port": "/dev/x"},
                                             "monitor": {"no_frames_s": 0.0}})
