"""The solver service without Zenoh: configuration, what a session turns into, the worker."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import pytest

from groundstation.errors import ConfigError, InputError
from groundstation.geodesy import ecef_to_llh
from groundstation.solve import service as sv
from groundstation.solve.pipeline import SolveResult
from groundstation.solve.settings import SolveSettings

XYZ = (4146349.2471, 612312.5498, 4791750.8505)


def test_defaults_connect_to_the_local_daemon_and_solve_nothing() -> None:
    s = sv.build_service_settings()
    assert s.station == "*" and s.bus.connect == ("tcp/127.0.0.1:7447",) and s.bus.listen == ()
    assert s.for_station("any").base is None and s.default.interp == "smoother"


def test_file_then_command_line() -> None:
    layer = {
        "out_root": "/data/solutions", "lever_arm": [0.1, 0.0, 0.3],
        "zenoh": {"connect": ["tcp/10.0.0.2:7447"], "mode": "client"},
        "stations": {"alpha": {"base": "{dir}/{stem}_base.ubx", "base_xyz": list(XYZ),
                               "photos": "/photos/{stem}", "interp": "linear", "epsg": 25832}},
    }
    s = sv.build_service_settings(layer, {"station": "alpha", "interp": "spline"})
    a = s.for_station("alpha")
    assert s.station == "alpha" and s.bus.mode == "client"
    assert a.base_ecef_m == XYZ and a.epsg == 25832 and a.out_root == Path("/data/solutions")
    assert a.interp == "spline"  # the command line wins over the station table
    assert a.lever_arm_m == (0.1, 0.0, 0.3)  # top-level defaults reach the station
    assert s.for_station("bravo").base is None
    cli = sv.build_service_settings(None, {"base": "b.ubx", "base_xyz": "4201000,180000,4779000"})
    assert cli.for_station("whoever").base_ecef_m == (4201000.0, 180000.0, 4779000.0)


def test_the_base_as_latitude_longitude_and_antenna_height() -> None:
    layer = {"stations": {"a": {"base": "b.ubx", "base_llh": [53.28, -8.98, 86.7],
                                "base_antenna_height_m": 1.5}}}
    a = sv.build_service_settings(layer).for_station("a")
    assert a.base_ecef_m is not None
    lat, lon, h = ecef_to_llh(*a.base_ecef_m)
    assert abs(lat - 53.28) < 1e-9 and abs(lon + 8.98) < 1e-9 and abs(h - 88.2) < 1e-6
    assert a.base_given.startswith("given with stations.a.base_llh 53.280000000,-8.98")
    assert a.base_given.endswith("1.5000 m above it (stations.a.base_antenna_height_m)")


@pytest.mark.parametrize(("layer", "key"), [
    ({"stations": {"a": {"base_xyz": [1, 2, "x"], "base": "b"}}}, "stations.a.base_xyz"),
    ({"stations": {"a": {"base": "b"}}}, "stations.a.base_xyz"),
    ({"stations": {"a": {"base_xyz": [4201000, 180000, 4779000]}}}, "stations.a.base"),
    ({"stations": {"a": {"edge": "up"}}}, "stations.a.edge"),
    ({"stations": {"a": {"base": "b", "base_llh": [95, 8, 100]}}}, "stations.a.base_llh"),
    ({"stations": {"a": {"base": "b", "base_antenna_height_m": 1.5}}},
     "stations.a.base_antenna_height_m"),
    ({"stations": {"a": {"base": "b", "base_llh": [53, -9, 90], "base_xyz": list(XYZ)}}},
     "stations.a.base_llh"),
    ({"stations": {"a": "b.ubx"}}, "stations.a"),
    ({"stations": {"a": {"max_gap_s": 0}}}, "stations.a.max_gap_s"),
    ({"epsg": "utm"}, "epsg"),
    ({"station": "a/b"}, "station"),
    ({"zenoh": {"connect": "tcp/x:1", "port": 1}}, "zenoh.port"),
    ({"solver": {}}, "solver"),
])
def test_bad_values_name_their_key(layer: dict[str, Any], key: str) -> None:
    with pytest.raises(ConfigError) as err:
        sv.build_service_settings(layer)
    assert err.value.key == key


def test_plan(tmp_path: Path) -> None:
    flight = tmp_path / "alpha_20250101T000000Z.mcap"
    (tmp_path / "photos" / flight.stem).mkdir(parents=True)
    conf = sv.StationSolve(base="{dir}/{stem}_base.ubx", base_ecef_m=XYZ,
                           photos=str(tmp_path / "photos" / "{stem}"), out_root=tmp_path / "out")
    msg = {"state": "finished", "files": [str(flight)], "session_id": "s"}
    assert sv.plan("alpha", {**msg, "state": "started"}, conf) == []
    (job,) = sv.plan("alpha", msg, conf)
    assert isinstance(job, sv.Job)
    assert job.settings.base == tmp_path / f"{flight.stem}_base.ubx"
    assert job.settings.photos == tmp_path / "photos" / flight.stem
    assert job.settings.out_dir == tmp_path / "out" / "alpha" / flight.stem
    (no_photos,) = sv.plan("alpha", {**msg, "files": [str(tmp_path / "other.mcap")]}, conf)
    assert isinstance(no_photos, sv.Job) and no_photos.settings.photos is None
    assert "solved without photos" in no_photos.notes[0]
    (skip,) = sv.plan("bravo", msg, sv.StationSolve())
    assert isinstance(skip, sv.Skip) and "no base configured for station 'bravo'" in skip.reason
    (empty,) = sv.plan("alpha", {**msg, "files": []}, conf)
    assert isinstance(empty, sv.Skip) and "no recording" in empty.reason


def test_report_pdf_false_reaches_every_job(tmp_path: Path) -> None:
    """``report_pdf = false`` (file, table or ``GROUNDSTATION_SOLVER_REPORT_PDF``): the jobs
    write report.html only; the default prints report.pdf too."""
    flight = tmp_path / "alpha_20250101T000000Z.mcap"
    msg = {"state": "finished", "files": [str(flight)], "session_id": "s"}
    env = sv.build_service_settings(
        {"base": "b.ubx", "base_xyz": list(XYZ)},
        environ={"GROUNDSTATION_SOLVER_REPORT_PDF": "false"})
    table = sv.build_service_settings(
        {"base": "b.ubx", "base_xyz": list(XYZ), "stations": {"alpha": {"report_pdf": False}}})
    for settings, station, pdf in ((env, "alpha", False), (table, "alpha", False),
                                   (table, "bravo", True)):
        (job,) = sv.plan(station, msg, settings.for_station(station))
        assert isinstance(job, sv.Job) and job.settings.report_pdf is pdf, station


class FakeSolver:
    """Blocks until released; fails for flights whose name says so."""

    def __init__(self) -> None:
        self.release = threading.Event()
        self.calls: list[SolveSettings] = []

    def __call__(self, s: SolveSettings) -> SolveResult:
        self.calls.append(s)
        self.release.wait(5)
        raise InputError(f"{s.flight.name}: no marks")


def test_worker_dedups_bounds_its_queue_and_survives_failures(tmp_path: Path) -> None:
    sent: list[tuple[str, dict[str, Any]]] = []
    settings = sv.ServiceSettings(
        default=sv.StationSolve(base=str(tmp_path / "base.ubx"), base_ecef_m=XYZ,
                                out_root=tmp_path / "out"),
        queue_size=1, recording_roots=(tmp_path,),
    )
    (tmp_path / "base.ubx").write_bytes(b"")
    for name in ("a.mcap", "b.mcap", "c.mcap"):
        (tmp_path / name).write_bytes(name.encode())
    fake = FakeSolver()
    service = sv.SolverService(settings, lambda st, body: sent.append((st, body)), solver=fake)
    stop = threading.Event()
    worker = threading.Thread(target=service.run, args=(stop,))
    worker.start()
    try:
        def finished(sid: str, name: str) -> None:
            service.on_session("alpha", {"state": "finished", "session_id": sid,
                                         "files": [str(tmp_path / name)]})

        finished("1", "a.mcap")
        for _ in range(100):  # the worker takes job 1 and blocks in the solver
            if fake.calls:
                break
            threading.Event().wait(0.01)
        finished("1", "a.mcap")  # repeat: ignored
        finished("2", "b.mcap")  # waits in the queue
        finished("3", "c.mcap")  # queue full: refused
        assert [b["status"] for _, b in sent] == ["solving", "failed"]
        assert "solver busy" in sent[1][1]["reason"] and sent[1][1]["session_id"] == "3"
        fake.release.set()
        for _ in range(200):
            if len(sent) >= 5:
                break
            threading.Event().wait(0.01)
    finally:
        stop.set()
        service.close()
        worker.join(5)
    statuses = [(b["session_id"], b["status"]) for _, b in sent]
    assert statuses == [("1", "solving"), ("3", "failed"), ("1", "failed"), ("2", "solving"),
                        ("2", "failed")]
    assert "InputError: a.mcap: no marks" in sent[2][1]["reason"]
    assert service.failed == 3 and service.solved == 0
    # A second solve of a flight never overwrites the first one's directory.
    (tmp_path / "out" / "alpha" / "d").mkdir(parents=True)
    job = sv.Job("alpha", "4", tmp_path / "d.mcap", SolveSettings(
        flight=tmp_path / "d.mcap", out_dir=tmp_path / "out" / "alpha" / "d"))
    service.solve_job(job)
    assert sent[-1][1]["out_dir"] == str(tmp_path / "out" / "alpha" / "d-2")
    assert "recording not found" in sent[-1][1]["reason"]
