"""Base pairing (rover session -> the base station's recording of the same time), its
configuration, the session span in the message rules, and the claim keys of shared workers."""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

import pytest
from peers import REPO

from groundstation import messages
from groundstation.errors import ConfigError, GroundstationError
from groundstation.solve import service as sv
from groundstation.solve.claims import CLAIM_ROOT, claim_prefix, job_key
from groundstation.solve.pairing import SPAN_SLACK_NS, Pairing, base_station

XYZ = [4146349.2471, 612312.5498, 4791750.8505]
S = 1_000_000_000
T0 = 1_400_000_000 * S


def _session(sid: str, first_s: float, last_s: float, state: str = "finished",
             files: list[str] | None = None) -> dict[str, Any]:
    return {"state": state, "session_id": sid, "files": files or [f"/rec/{sid}.mcap"],
            "first_epoch_t_gps_ns": T0 + int(first_s * S),
            "last_epoch_t_gps_ns": T0 + int(last_s * S)}


def _pairing(wait_s: float = 0.0) -> Pairing:
    return Pairing(lambda p: sv.confine(p, (Path("/rec"),)), wait_s)


def test_the_base_session_covering_the_rover_is_picked() -> None:
    pairing = _pairing()
    pairing.note("base", _session("base_morning", 0, 3600))
    pairing.note("base", _session("base_noon", 4000, 8000))
    pairing.note("rover", _session("rover_1", 4100, 4200))  # another station: not a base
    notes: list[str] = []
    got = pairing.base_for("base", (T0 + 4100 * S, T0 + 4200 * S), threading.Event(), notes)
    assert got == Path("/rec/base_noon.mcap").resolve()
    assert notes == ["base: station 'base', session base_noon, base_noon.mcap"]
    # the daemon's span may end a status interval short: within the slack still covers
    notes.clear()
    end = T0 + 8000 * S + SPAN_SLACK_NS // 2
    pairing.base_for("base", (T0 + 7000 * S, end), threading.Event(), notes)
    assert not [n for n in notes if "covers" in n]


def test_partial_cover_is_used_with_a_note_and_none_is_an_error() -> None:
    pairing = _pairing()
    pairing.note("base", _session("b1", 0, 100))
    notes: list[str] = []
    pairing.base_for("base", (T0 + 50 * S, T0 + 150 * S), threading.Event(), notes)
    assert any("covers 50 s of the rover's 100 s" in n for n in notes)
    with pytest.raises(GroundstationError, match="no recording of base station 'base' covers"):
        pairing.base_for("base", (T0 + 500 * S, T0 + 600 * S), threading.Event(), [])
    with pytest.raises(GroundstationError, match="no recording of base station 'other'"):
        pairing.base_for("other", (T0, T0 + S), threading.Event(), [])
    with pytest.raises(GroundstationError, match="carries no epoch span"):
        pairing.base_for("base", None, threading.Event(), [])


def test_a_base_never_heard_of_and_not_answering_fails_at_once() -> None:
    pairing = _pairing(wait_s=3600.0)  # no wait: there is nothing to wait for
    pairing.ask = lambda station: None
    with pytest.raises(GroundstationError, match="no session of it heard and no daemon"):
        pairing.base_for("base", (T0, T0 + S), threading.Event(), [])


def test_a_base_outside_the_recording_roots_is_refused() -> None:
    pairing = _pairing()
    pairing.note("base", _session("b1", 0, 100, files=["/etc/b1.mcap"]))
    with pytest.raises(GroundstationError, match="recording refused: outside"):
        pairing.base_for("base", (T0 + 10 * S, T0 + 20 * S), threading.Event(), [])


def test_the_wait_for_a_base_still_recording_ends_when_it_covers() -> None:
    pairing = _pairing(wait_s=30.0)
    pairing.note("base", _session("b1", 0, 50, state="started"))
    asked: list[str] = []

    def ask(station: str) -> dict[str, Any]:  # the base daemon's q/session, recording on
        asked.append(station)
        return _session("b1", 0, 50 + 40 * len(asked), state="started")

    pairing.ask = ask
    notes: list[str] = []
    got = pairing.base_for("base", (T0 + 10 * S, T0 + 120 * S), threading.Event(), notes)
    assert got.name == "b1.mcap" and asked == ["base", "base"]
    assert any("waited for base station 'base'" in n for n in notes)


def test_base_values_and_their_keys() -> None:
    assert base_station("{dir}/{stem}_base.ubx") is None
    assert base_station("/data/base.ubx") is None
    assert base_station("station:base") == "base"
    settings = sv.build_service_settings({"stations": {
        "rover": {"base": "station:base", "base_xyz": XYZ}}})
    assert settings.base_stations() == {"base"}
    job = sv.plan("rover", {"state": "finished", "session_id": "s", "files": ["/f/r.mcap"],
                            "first_epoch_t_gps_ns": T0, "last_epoch_t_gps_ns": T0 + S},
                  settings.for_station("rover"))[0]
    assert isinstance(job, sv.Job)
    assert job.base_station == "base" and job.settings.base is None
    assert job.span_ns == (T0, T0 + S)


@pytest.mark.parametrize(("layer", "key"), [
    ({"stations": {"rover": {"base": "station:rover", "base_xyz": XYZ}}}, "stations.rover.base"),
    ({"stations": {"rover": {"base": "station:", "base_xyz": XYZ}}}, "stations.rover.base"),
    ({"stations": {"rover": {"base": "station:a/b", "base_xyz": XYZ}}}, "stations.rover.base"),
    ({"stations": {"rover": {"base": "stations:base", "base_xyz": XYZ}}}, "stations.rover.base"),
    ({"base": "Station:base", "base_xyz": XYZ}, "base"),
    ({"base_wait_s": -1}, "base_wait_s"),
])
def test_bad_base_values_name_their_key(layer: dict[str, Any], key: str) -> None:
    with pytest.raises(ConfigError) as err:
        sv.build_service_settings(layer)
    assert err.value.key == key


def test_a_bad_base_station_exits_2_naming_the_key(tmp_path: Path) -> None:
    conf = tmp_path / "solver.toml"
    conf.write_text('[stations.rover]\nbase = "station:rover"\nbase_xyz = '
                    f"[{', '.join(map(str, XYZ))}]\n")
    proc = subprocess.run(
        [sys.executable, "-m", "groundstation.cli", "solver", "--config", str(conf)],
        cwd=REPO, capture_output=True, text=True, timeout=60, check=False)
    assert proc.returncode == 2, proc.stderr
    assert "configuration error: stations.rover.base:" in proc.stderr
    assert "cannot be its own base" in proc.stderr and "Traceback" not in proc.stderr


def test_a_station_is_not_its_own_base_by_default() -> None:
    settings = sv.build_service_settings({"base": "station:base", "base_xyz": XYZ})
    (skip,) = sv.plan("base", {"state": "finished", "session_id": "s", "files": ["/f/b.mcap"]},
                      settings.for_station("base"))
    assert isinstance(skip, sv.Skip) and "is its own base" in skip.reason


def test_the_session_span_is_checked() -> None:
    ok = {"type": "session", "first_epoch_t_gps_ns": T0, "last_epoch_t_gps_ns": T0 + S}
    assert messages.check(ok, "session") == ok
    with pytest.raises(messages.BadMessage, match="first epoch .* after last"):
        messages.check({**ok, "first_epoch_t_gps_ns": T0 + 2 * S}, "session")
    with pytest.raises(messages.BadMessage, match="first_epoch_t_gps_ns"):
        messages.check({**ok, "first_epoch_t_gps_ns": -1}, "session")


def test_claim_keys_are_one_chunk_per_part_whatever_the_names() -> None:
    job = job_key("rover", "rover_20260101T000000Z", "/a/b/rover_20260101T000000Z.mcap")
    assert job == ("rover", "rover_20260101T000000Z", "rover_20260101T000000Z.mcap")
    assert claim_prefix(job) == (f"{CLAIM_ROOT}/rover/rover_20260101T000000Z/"
                                 "rover_20260101T000000Z.mcap")
    odd = claim_prefix(("r", "a/b*$c", ".."))
    assert odd == f"{CLAIM_ROOT}/r/a_b__c/_.."
    assert not set("*$#?") & set(odd)


def test_a_base_stations_sessions_are_kept_for_pairing_not_answered() -> None:
    settings = sv.build_service_settings({"recording_roots": ["/rec"], "stations": {
        "rover": {"base": "station:base", "base_xyz": XYZ}}})
    sent: list[tuple[str, dict[str, Any]]] = []
    service = sv.SolverService(settings, lambda st, body: sent.append((st, body)))
    service.on_session("base", _session("base_1", 0, 100))
    service.on_session("other", _session("other_1", 0, 100))
    assert [(st, body["status"]) for st, body in sent] == [("other", "skipped")]
    got = service.pairing.base_for("base", (T0 + S, T0 + 2 * S), threading.Event(), [])
    assert got.name == "base_1.mcap"
