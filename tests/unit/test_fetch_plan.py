"""Which recordings the solver fetches over the bus (``solve/fetch.remote_for`` through
``service.plan``), the ``fetch`` key, and the latest-solution store of ``q/solution``."""

from __future__ import annotations

from pathlib import Path

import pytest

from groundstation.bus import encode
from groundstation.errors import ConfigError, GroundstationError
from groundstation.solve import service as sv
from groundstation.solve.fetch import remote_for
from groundstation.solve.solutions import LatestSolutions

XYZ = (4146349.2471, 612312.5498, 4791750.8505)
NAME = "alpha_20250101T000000Z.mcap"
ENTRY = {"name": NAME, "size": 1234, "sha256": "ab" * 32, "chunk_bytes": 65536}


def _conf(tmp: Path, fetch: str = "auto") -> sv.StationSolve:
    return sv.StationSolve(base="/bases/{stem}_base.ubx", base_ecef_m=XYZ,
                           out_root=tmp / "out", fetch=fetch)


def _msg(path: str, recordings: list[dict[str, object]] | None = None) -> dict[str, object]:
    return {"state": "finished", "files": [path], "session_id": "alpha_20250101T000000Z",
            "recordings": [ENTRY] if recordings is None else recordings}


def test_a_recording_elsewhere_is_fetched_into_out_root(tmp_path: Path) -> None:
    roots = (tmp_path / "flights",)
    (job,) = sv.plan("alpha", _msg(f"/far/away/{NAME}"), _conf(tmp_path), roots)
    assert isinstance(job, sv.Job) and job.remote is not None
    assert job.flight == job.remote.dest == tmp_path / "out" / "alpha" / NAME
    assert job.remote.key_expr == "groundstation/alpha/q/recording/alpha_20250101T000000Z"
    assert (job.remote.size, job.remote.sha256) == (1234, "ab" * 32)
    assert job.settings.base == Path("/bases/alpha_20250101T000000Z_base.ubx")
    assert job.settings.out_dir == tmp_path / "out" / "alpha" / Path(NAME).stem


def test_a_readable_recording_in_the_roots_is_solved_in_place(tmp_path: Path) -> None:
    local = tmp_path / "flights" / NAME
    local.parent.mkdir()
    local.write_bytes(b"x")
    roots = (tmp_path / "flights",)
    (job,) = sv.plan("alpha", _msg(str(local)), _conf(tmp_path), roots)
    assert isinstance(job, sv.Job) and job.remote is None and job.flight == local.resolve()
    (always,) = sv.plan("alpha", _msg(str(local)), _conf(tmp_path, "always"), roots)
    assert isinstance(always, sv.Job) and always.remote is not None


def test_without_a_served_copy_or_with_fetch_never_a_path_outside_is_refused(
        tmp_path: Path) -> None:
    roots = (tmp_path / "flights",)
    far = f"/far/away/{NAME}"
    (never,) = sv.plan("alpha", _msg(far), _conf(tmp_path, "never"), roots)
    assert isinstance(never, sv.Refusal)
    other = {**ENTRY, "name": "alpha_20250101T000001Z.mcap"}
    (unlisted,) = sv.plan("alpha", _msg(far, [other]), _conf(tmp_path), roots)
    assert isinstance(unlisted, sv.Refusal)  # recordings[] does not name this file
    (none,) = sv.plan("alpha", _msg(far, []), _conf(tmp_path), roots)
    assert isinstance(none, sv.Refusal)


def test_a_session_id_that_is_no_key_chunk_is_not_fetched(tmp_path: Path) -> None:
    for sid in ("a/b", "*", "", "a?b", "$x"):
        msg = {**_msg(f"/far/{NAME}"), "session_id": sid}
        assert remote_for("alpha", msg, Path(f"/far/{NAME}"), tmp_path, None) is None


def test_a_fetch_without_a_bus_fails_with_a_reason(tmp_path: Path) -> None:
    sent: list[dict[str, object]] = []
    settings = sv.ServiceSettings(default=_conf(tmp_path), recording_roots=(tmp_path,))
    service = sv.SolverService(settings, lambda st, body: sent.append(body))
    (job,) = sv.plan("alpha", _msg(f"/far/away/{NAME}"), settings.default, (tmp_path,))
    assert isinstance(job, sv.Job)
    service.solve_job(job)
    assert [m["status"] for m in sent] == ["solving", "failed"]
    assert "no bus to fetch it over" in str(sent[1]["reason"])


@pytest.mark.parametrize(("layer", "key"), [
    ({"fetch": "maybe"}, "fetch"),
    ({"stations": {"a": {"fetch": True}}}, "stations.a.fetch"),
])
def test_bad_fetch_values_name_their_key(layer: dict[str, object], key: str) -> None:
    with pytest.raises(ConfigError) as err:
        sv.build_service_settings(layer)
    assert err.value.key == key


def test_fetch_per_station() -> None:
    s = sv.build_service_settings({"fetch": "never", "stations": {"a": {"fetch": "always"}}})
    assert s.default.fetch == "never" and s.for_station("a").fetch == "always"


def test_latest_solution_per_recording_answers_matching_keys() -> None:
    latest = LatestSolutions(max_recordings=2)
    for station, sid, status in [("rover", "s1", "solving"), ("rover", "s1", "ok"),
                                 ("base", "s2", "failed")]:
        body = {"status": status, "session_id": sid, "flight": f"/x/{sid}.mcap"}
        latest.keep(station, body, encode("solution", body))
    rover = latest.answer("groundstation/rover/q/solution", {})
    assert [r.key for r in rover] == ["groundstation/rover/q/solution"]
    assert b'"ok"' in rover[0].payload  # the latest replaced "solving"
    everyone = latest.answer("groundstation/*/q/solution", {})
    assert [r.key for r in everyone] == ["groundstation/rover/q/solution",
                                         "groundstation/base/q/solution"]
    body = {"status": "ok", "session_id": "s3", "flight": "/x/s3.mcap"}
    latest.keep("rover", body, encode("solution", body))  # the oldest goes beyond 2
    assert len(latest.answer("groundstation/**", {})) == 2
    assert latest.answer("groundstation/nobody/q/solution", {}) == []


def test_an_announced_size_beyond_the_free_disk_is_not_fetched(tmp_path: Path) -> None:
    from groundstation.bus import open_bus
    from groundstation.config import ZenohSettings
    from groundstation.solve.fetch import Fetcher, Remote

    remote = Remote("alpha", "s", NAME, 1 << 50, "ab" * 32, 65536, tmp_path / "alpha" / NAME)
    bus = open_bus(ZenohSettings(listen=(), connect=()))  # a session on its own
    try:
        with pytest.raises(GroundstationError, match="free in"):
            Fetcher(bus).fetch(remote)
    finally:
        bus.close()
    assert not any((tmp_path / "alpha").iterdir())  # not even a .part


@pytest.mark.parametrize(("env", "key"), [
    ({"GROUNDSTATION_ZENOH_SERVE_AFTER_S": "-1"}, "zenoh.serve_after_s"),
    ({"GROUNDSTATION_ZENOH_SERVE_RECORDINGS": "perhaps"}, "zenoh.serve_recordings"),
])
def test_the_daemon_serving_keys_are_checked(env: dict[str, str], key: str) -> None:
    from groundstation.config import load_settings

    source = {"source": {"path": "flight.ubx"}}
    with pytest.raises(ConfigError) as err:
        load_settings(None, environ=env, overrides=source)
    assert err.value.key == key
    ok = load_settings(None, environ={"GROUNDSTATION_ZENOH_SERVE_AFTER_S": "600"},
                       overrides=source)
    assert ok.zenoh.serve_after_s == 600.0 and ok.zenoh.serve_recordings
