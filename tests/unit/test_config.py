"""Configuration resolution: layers, precedence and errors that name the key."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from groundstation.config import (
    FileSourceSettings,
    SerialSourceSettings,
    TcpSourceSettings,
    load_settings,
)
from groundstation.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "gs.toml"
    path.write_text(text)
    return path


def test_example_config_loads() -> None:
    settings = load_settings(REPO / "config" / "groundstation.toml", environ={})
    assert isinstance(settings.source, SerialSourceSettings)
    # One story: the example, the LEA-6T profile and the README's field steps say 57600 baud;
    # the README, the demo and the daemon record to flights/.
    assert settings.source.baud == 57600
    profile = (REPO / "config" / "profiles" / "lea6t-5hz.toml").read_text(encoding="utf-8")
    assert "baudRate = 57600" in profile
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    assert "groundstation run --port /dev/wi232 --baud 57600 --station rover" in readme
    assert settings.recorder.out_dir == load_settings(None, environ={}, overrides={
        "source": {"port": "/dev/x"}}).recorder.out_dir == Path("flights")
    assert settings.recorder.flush_interval_s <= 1.0


def test_precedence_defaults_file_env_cli(tmp_path: Path) -> None:
    cfg = write(tmp_path, 'station = "file"\n[source]\nport = "/dev/a"\nbaud = 9600\n'
                          '[recorder]\nrotate_size_mb = 5\n')
    s = load_settings(cfg, environ={})
    assert (s.station, s.source, s.recorder.rotate_size_mb) == (
        "file", SerialSourceSettings(port="/dev/a", baud=9600), 5.0)
    assert s.recorder.flush_interval_s == 0.5  # default
    env = {"GROUNDSTATION_STATION": "env", "GROUNDSTATION_SOURCE_BAUD": "57600",
           "GROUNDSTATION_RECORDER_SIDECAR": "false", "UNRELATED": "x"}
    s = load_settings(cfg, environ=env)
    assert (s.station, s.source.baud, s.recorder.sidecar) == ("env", 57600, False)  # type: ignore[union-attr]
    s = load_settings(cfg, environ=env, overrides={"station": "cli", "source": {"baud": 115200}})
    assert (s.station, s.source.baud) == ("cli", 115200)  # type: ignore[union-attr]


def test_cli_source_replaces_file_source(tmp_path: Path) -> None:
    cfg = write(tmp_path, '[source]\ntype = "serial"\nport = "/dev/a"\n')
    s = load_settings(cfg, environ={}, overrides={"source": {"address": "gnss.local:5000"}})
    assert s.source == TcpSourceSettings(host="gnss.local", port=5000)
    s = load_settings(cfg, environ={}, overrides={"source": {"path": Path("x.ubx.gz")}})
    assert s.source == FileSourceSettings(path=Path("x.ubx.gz"))


def test_config_file_from_environment(tmp_path: Path) -> None:
    cfg = write(tmp_path, '[source]\nport = "/dev/b"\n')
    s = load_settings(None, environ={"GROUNDSTATION_CONFIG": str(cfg)})
    assert s.source == SerialSourceSettings(port="/dev/b")


@pytest.mark.parametrize(
    ("text", "overrides", "key"),
    [
        ('bogus = 1\n[source]\nport = "/dev/a"\n', None, "bogus"),
        ('[source]\nport = "/dev/a"\nparity = "E"\n', None, "source.parity"),
        ('[recorder]\nflush_every = 1\n[source]\nport = "/dev/a"\n', None, "recorder.flush_every"),
        ('[nonsense]\nx = 1\n', None, "nonsense"),
        ("station = \"a\"\n", None, "source"),
        ('[source]\nport = "/dev/a"\nbaud = 12345\n', None, "source.baud"),
        ('[source]\nport = "/dev/a"\nbaud = "fast"\n', None, "source.baud"),
        ('[source]\nport = "/dev/a"\n', {"source": {"baud": -1}}, "source.baud"),
        ('[source]\ntype = "usb"\n', None, "source.type"),
        ('[source]\ntype = "tcp"\n', None, "source.address"),
        ('[source]\naddress = "nohost"\n', None, "source.address"),
        ('[source]\nport = "/dev/a"\n[recorder]\nflush_interval_s = 5\n', None,
         "recorder.flush_interval_s"),
        ('station = "a b"\n[source]\nport = "/dev/a"\n', None, "station"),
        ("[source\n", None, "config"),
    ],
)
def test_bad_configuration_names_the_key(
    tmp_path: Path, text: str, overrides: dict[str, object] | None, key: str
) -> None:
    with pytest.raises(ConfigError) as info:
        load_settings(write(tmp_path, text), environ={}, overrides=overrides)
    assert info.value.key == key
    assert key in str(info.value)


def test_bad_environment_value_names_the_key() -> None:
    with pytest.raises(ConfigError) as info:
        load_settings(None, environ={"GROUNDSTATION_SOURCE_PORT": "/dev/a",
                                     "GROUNDSTATION_SOURCE_BAUD": "abc"})
    assert info.value.key == "source.baud"


def test_settings_are_frozen_and_jsonable(tmp_path: Path) -> None:
    s = load_settings(write(tmp_path, '[source]\npath = "a.ubx"\n'), environ={})
    with pytest.raises(AttributeError):
        s.station = "x"  # type: ignore[misc]
    assert s.to_jsonable()["source"]["path"] == "a.ubx"


@pytest.mark.parametrize(
    ("text", "key"),
    [
        ('status_interval_s = nan\n', "status_interval_s"),
        ('status_interval_s = 1e-9\n', "status_interval_s"),
        ('duration_s = inf\n', "duration_s"),
        ('[source]\nread_size_bytes = 1000000000000\n', "source.read_size_bytes"),
        ('[recorder]\nflush_interval_s = nan\n', "recorder.flush_interval_s"),
        ('[recorder]\nrotate_size_mb = inf\n', "recorder.rotate_size_mb"),
        ('[recorder]\nrotate_duration_s = -inf\n', "recorder.rotate_duration_s"),
        ('[recorder]\nretry_s = nan\n', "recorder.retry_s"),
        ('[recorder]\ncompression = "gzip"\n', "recorder.compression"),
        ('[monitor]\nelevation_mask_deg = 91\n', "monitor.elevation_mask_deg"),
        ('[monitor]\nhalf_cycle_fraction_max = 0\n', "monitor.half_cycle_fraction_max"),
        ('[zenoh]\nlisten = ["foo"]\n', "zenoh.listen"),
        ('[zenoh]\nconnect = ["tcp/127.0.0.1:99999"]\n', "zenoh.connect"),
        ('[zenoh]\nmode = "bogus"\n', "zenoh.mode"),
        ('[queues]\nmonitor = 0\n', "queues.monitor"),
    ],
)
def test_numbers_finite_and_in_range(tmp_path: Path, text: str, key: str) -> None:
    source = "" if "[source]" in text else '[source]\nport = "/dev/a"\n'
    cfg = write(tmp_path, text + source)  # a valid source: the bad number is the only fault
    with pytest.raises(ConfigError) as info:
        load_settings(cfg, environ={})
    assert info.value.key == key


@pytest.mark.parametrize(
    ("var", "value", "key"),
    [
        ("GROUNDSTATION_SOURCE_BAUD", "fast", "source.baud"),
        ("GROUNDSTATION_STATUS_INTERVAL_S", "nan", "status_interval_s"),
        ("GROUNDSTATION_SOURCE_READ_SIZE_BYTES", "1e12", "source.read_size_bytes"),
        ("GROUNDSTATION_RECORDER_SIDECAR", "maybe", "recorder.sidecar"),
        ("GROUNDSTATION_ZENOH_LISTEN", "foo", "zenoh.listen"),
    ],
)
def test_bad_environment_value_names_key_and_variable(var: str, value: str, key: str) -> None:
    with pytest.raises(ConfigError) as info:
        load_settings(None, environ={"GROUNDSTATION_SOURCE_PORT": "/dev/a", var: value})
    assert info.value.key == key
    assert var in str(info.value)


def test_unknown_variable_is_refused_naming_it() -> None:
    with pytest.raises(ConfigError) as info:
        load_settings(None, environ={"GROUNDSTATION_SOURCE_BAUDRATE": "9600",
                                     "GROUNDSTATION_SOURCE_PORT": "/dev/a"})
    assert info.value.key == "GROUNDSTATION_SOURCE_BAUDRATE"
    # a variable of another command is known (one shell may serve the daemon and the solver)
    s = load_settings(None, environ={"GROUNDSTATION_SOLVER_BASE": "b.ubx",
                                     "GROUNDSTATION_SOURCE_PORT": "/dev/a"})
    assert s.source == SerialSourceSettings(port="/dev/a")


def test_config_path_that_is_no_regular_utf8_file(tmp_path: Path) -> None:
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)
    binary = tmp_path / "bin.toml"
    binary.write_bytes(b'station = "\xff\xfe"\n')
    for path, words in ((tmp_path, "is a directory"), (fifo, "not a regular file"),
                        (binary, "not UTF-8"), (tmp_path / "missing.toml", "not found")):
        with pytest.raises(ConfigError) as info:
            load_settings(path, environ={})
        assert info.value.key == "config" and words in str(info.value)
