"""Configuration resolution: layers, precedence and errors that name the key."""

from __future__ import annotations

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
    assert settings.source.baud == 115200
    assert settings.recorder.flush_interval_s <= 1.0


def test_precedence_defaults_file_env_cli(tmp_path: Path) -> None:
    cfg = write(tmp_path, 'station = "file"\n[source]\nport = "/dev/a"\nbaud = 9600\n'
                          '[recorder]\nrotate_size_mb = 5\n')
    s = load_settings(cfg, environ={})
    assert (s.station, s.source, s.recorder.rotate_size_mb) == (
        "file", SerialSourceSettings(port="/dev/a", baud=9600), 5.0)
    assert s.recorder.flush_interval_s == 0.5  # default
    env = {"GROUNDSTATION_STATION": "env", "GROUNDSTATION_SOURCE_BAUD": "57600",
           "GROUNDSTATION_RECORDER_SIDECAR": "false", "GROUNDSTATION_UNRELATED": "x"}
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
