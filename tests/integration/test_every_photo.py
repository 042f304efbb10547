"""Every photo gets a position, and every lost mark its cause (a seed-profile flight, a photo per
exposure, the camera clock 1 h 0 min 37 s off UTC and drifting 20 ppm, 10 ms EXIF sub-seconds).

Photos paired with a received mark keep its time; the others are timed by the camera clock
fitted on the paired ones, flagged ``camera_clock``, and must lie within max(10 cm, 3 sigma) of
the truth like any position. The marks the radio lost and the ones the receiver did not
report are counted apart, in the solve's printout, the report and the monitor's events, against
the simulator's truth. A pulse the receiver did not report whose epoch the link lost too is
evidence for both: it may be counted either way.
"""

from __future__ import annotations

import csv
import re
from typing import Any

import numpy as np
import pytest
from once import cli_without_rtklib

from groundstation.geodesy import ecef_to_enu, llh_to_ecef
from groundstation.live.monitor import Monitor
from groundstation.records import DamagedData, Event
from groundstation.sim.faults import FaultConfig
from groundstation.sim.profiles import DEFAULT_FAULTS, sim_config
from groundstation.sim.stream import simulate
from groundstation.solve.photosim import photos_at_times, write_photo_set
from groundstation.ubx.decode import Decoder
from groundstation.ubx.framer import BetweenFrames, UbxFramer

pytestmark = pytest.mark.xdist_group("test_every_photo")

IV = 200_000_000


def _truth_causes(truth: dict[str, Any], received: int) -> tuple[int, int, int]:
    """(lost on the link, not reported by the receiver, of those both): the pulses the
    receiver did not report are the simulator's; every other pulse not received was lost on
    the link; a pulse not reported whose epoch the link lost too is evidence for both."""
    s0 = int(truth["start_gps_ns"])
    lost_epochs = set(truth["fault_summary"]["epochs_lost_tow_ms"])
    missed = [e for e in truth["exposures"] if e["missed"]]
    both = 0
    for e in missed:
        epoch = s0 + -(-(int(e["falling_t_gps_ns"]) - s0) // IV) * IV
        both += (epoch % (604_800 * 10**9)) // 1_000_000 in lost_epochs
    return len(truth["exposures"]) - len(missed) - received, len(missed), both


def _monitor_events(rover_chunks: list[tuple[int, bytes]]) -> list[Event]:
    """The monitor over the stream as the ground received it, fed as the daemon's pipeline
    feeds it: the records, and where damaged data came between frames."""
    framer, decoder, between, monitor = UbxFramer(), Decoder(), BetweenFrames(), Monitor("sim")
    events: list[Event] = []
    for t_gps, chunk in rover_chunks:
        now = t_gps + 60_000_000
        monitor.on_bytes(len(chunk), now)
        between.feed(chunk)
        for frame in framer.feed(chunk, now):
            if between.damaged_before(frame):
                events += monitor.observe(DamagedData(now), now)
            events += monitor.observe(decoder.decode(frame), now)
        events += monitor.tick(now)[1]
    return events


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("every_photo")
    result = simulate(sim_config("seed", duration_s=1500, seed=11, severity=0.5,
                                 faults=FaultConfig.load(DEFAULT_FAULTS["seed"])))
    (d / "f.ubx").write_bytes(result.rover_bytes)
    (d / "b.ubx").write_bytes(result.base_bytes)
    truth = result.truth
    exposures = truth["exposures"]
    write_photo_set(photos_at_times([e["falling_t_gps_ns"] for e in exposures],
                                    clock_error_s=3637.0, subsec=True, drift_ppm=20.0),
                    d / "photos")
    xyz = ",".join(f"{v:.4f}" for v in truth["base"]["ecef_m"])
    proc = cli_without_rtklib("solve", "--no-pdf", "f.ubx", "--base", "b.ubx", "--base-xyz", xyz,
                              "--photos", "photos", "--out-dir", "out", "--no-progress", cwd=d)
    assert proc.returncode == 0, proc.stderr
    rows = list(csv.DictReader(ln for ln in (d / "out" / "cameras.csv").read_text().splitlines()
                               if not ln.startswith("#")))
    return {"dir": d, "truth": truth, "stdout": proc.stdout, "rows": rows,
            "events": _monitor_events(result.rover_chunks)}


def test_every_photo_is_positioned_and_those_timed_by_the_camera_clock_are_honest(
        flight: dict[str, Any]) -> None:
    exposures = flight["truth"]["exposures"]
    photos = [r for r in flight["rows"] if r["photo"]]
    assert len(photos) == len(exposures) and all(r["lat_deg"] for r in photos)
    by_clock = [r for r in photos if "camera_clock" in r["flags"].split(";")]
    paired = [r for r in photos if r["mark"]]
    received = len([m for m in flight["rows"] if m["mark"]])
    assert len(paired) == received and len(by_clock) == len(photos) - len(paired) > 0
    assert not any("camera_clock" in r["flags"] for r in paired)
    ok = 0
    for r in by_clock:
        k = int(r["photo"][4:8]) - 1
        got = llh_to_ecef(float(r["lat_deg"]), float(r["lon_deg"]), float(r["ellipsoidal_h_m"]))
        err = np.abs(ecef_to_enu(got, tuple(exposures[k]["ecef_m"])))
        sd = np.array([float(r[f"sd_{a}_m"]) for a in "enu"])
        ok += bool(np.all(err <= np.maximum(0.10, 3 * sd)))
        # named by the lost mark it stands for where the count jump says which
        if r["mark_count"]:
            assert int(r["mark_count"]) == exposures[k]["number"]
    assert ok >= 0.99 * len(by_clock), (ok, len(by_clock))


def _said(text: str, cause: str) -> int:
    m = re.search(rf"(\d+) time mark\(s\) {cause}", text)
    return int(m.group(1)) if m else 0


def test_lost_marks_are_counted_by_cause_as_the_truth_says(flight: dict[str, Any]) -> None:
    received = len([r for r in flight["rows"] if r["mark"]])
    link, missed, both = _truth_causes(flight["truth"], received)
    assert link > 0 and missed > 0, "the seed profile must lose marks both ways"
    on_link = _said(flight["stdout"], "lost on the radio link")
    in_receiver = _said(flight["stdout"], "not reported by the receiver")
    assert on_link + in_receiver == link + missed
    assert link <= on_link <= link + both, (on_link, link, missed, both)
    report = (flight["dir"] / "out" / "report.html").read_text()
    assert f'data-count="marks_lost_on_link">{on_link}<' in report
    assert f'data-count="marks_not_reported">{in_receiver}<' in report
    # the monitor, live: the same rule on what the daemon's pipeline gives it; it learns of a
    # lost pulse from the next received mark's count, so not of those before the first
    # received mark or after the last (no photos live)
    numbers = [int(r["mark_count"]) for r in flight["rows"] if r["mark"]]
    exposures = flight["truth"]["exposures"]
    # the exports' numbers are the truth's (every paired photo)
    assert all(int(r["mark_count"]) == exposures[int(r["photo"][4:8]) - 1]["number"]
               for r in flight["rows"] if r["mark"] and r["photo"])
    edge = [e for e in exposures if not min(numbers) <= e["number"] <= max(numbers)]
    edge_missed = sum(bool(e["missed"]) for e in edge)
    missed_events = [e for e in flight["events"] if e.kind == "mark.missed"]
    live_link = sum(e.data["lost_on_link"] for e in missed_events)
    live_receiver = sum(e.data["not_reported"] for e in missed_events)
    assert live_link + live_receiver == link + missed - len(edge)
    assert link - (len(edge) - edge_missed) <= live_link <= link - (len(edge) - edge_missed) + both
    assert live_receiver >= missed - edge_missed - both
    assert all(("lost on the radio link" in e.message) == (e.data["lost_on_link"] > 0)
               for e in missed_events)
