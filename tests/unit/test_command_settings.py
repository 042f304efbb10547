"""Every command's settings come from the one resolver: defaults < file < environment < options.

For ``run``, ``solver``, ``watch`` and ``dashboard`` the same Zenoh key is set in each layer in
turn and the command's own settings function (the one its ``run`` uses) must show the highest
layer's value; a bad key in each layer must make ``groundstation <command>`` exit 2 with one
line naming the key (and, for the environment, the variable).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from groundstation import cli
from groundstation.config import DEFAULT_ENDPOINT, ZenohSettings, load_settings
from groundstation.errors import ConfigError


@dataclass(frozen=True)
class Command:
    name: str
    env_prefix: str
    connect_option: str
    base_args: tuple[str, ...]
    zenoh: Callable[[argparse.Namespace], ZenohSettings]
    default_connect: tuple[str, ...]


def _run(args: argparse.Namespace) -> ZenohSettings:
    from groundstation.commands.run import overrides_from_args

    return load_settings(args.config, overrides=overrides_from_args(args)).zenoh


def _solver(args: argparse.Namespace) -> ZenohSettings:
    from groundstation.commands.solver import overrides_from_args
    from groundstation.solve.service import load_service_settings

    return load_service_settings(args.config, overrides_from_args(args)).bus


def _watch(args: argparse.Namespace) -> ZenohSettings:
    from groundstation.commands.watch import settings_from_args

    return settings_from_args(args)[1]


def _dashboard(args: argparse.Namespace) -> ZenohSettings:
    from groundstation.commands.dashboard import settings_from_args

    return settings_from_args(args)[0].bus


COMMANDS = [
    Command("run", "GROUNDSTATION_", "--zenoh-connect", ("--port", "/dev/nonexistent-gs"),
            _run, ()),
    Command("solver", "GROUNDSTATION_SOLVER_", "--zenoh-connect", (), _solver,
            (DEFAULT_ENDPOINT,)),
    Command("watch", "GROUNDSTATION_WATCH_", "--zenoh-connect", (), _watch, (DEFAULT_ENDPOINT,)),
    Command("dashboard", "GROUNDSTATION_DASHBOARD_", "--zenoh-connect", (), _dashboard,
            (DEFAULT_ENDPOINT,)),
]
IDS = [c.name for c in COMMANDS]


def parse(argv: list[str]) -> argparse.Namespace:
    return cli.build_parser(argv).parse_args(argv)


@pytest.fixture(autouse=True)
def _clean_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    import os

    for var in list(os.environ):
        if var.startswith("GROUNDSTATION_"):
            monkeypatch.delenv(var)


@pytest.mark.parametrize("cmd", COMMANDS, ids=IDS)
def test_precedence_defaults_file_environment_options(
    cmd: Command, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cfg = tmp_path / "c.toml"
    cfg.write_text('[zenoh]\nconnect = ["tcp/10.0.0.1:7001"]\n', encoding="utf-8")
    argv = [cmd.name, *cmd.base_args]
    assert cmd.zenoh(parse(argv)).connect == cmd.default_connect
    assert cmd.zenoh(parse([*argv, "--config", str(cfg)])).connect == ("tcp/10.0.0.1:7001",)
    monkeypatch.setenv(f"{cmd.env_prefix}CONFIG", str(cfg))  # the file named by the variable
    assert cmd.zenoh(parse(argv)).connect == ("tcp/10.0.0.1:7001",)
    monkeypatch.setenv(f"{cmd.env_prefix}ZENOH_CONNECT", "tcp/10.0.0.2:7002")
    assert cmd.zenoh(parse(argv)).connect == ("tcp/10.0.0.2:7002",)
    got = cmd.zenoh(parse([*argv, cmd.connect_option, "tcp/10.0.0.3:7003"]))
    assert got.connect == ("tcp/10.0.0.3:7003",)


@pytest.mark.parametrize("cmd", [c for c in COMMANDS if c.name != "run"], ids=IDS[1:])
def test_clients_listen_nowhere_by_default(cmd: Command) -> None:
    assert cmd.zenoh(parse([cmd.name])).listen == ()
    # one name per option everywhere; the clients' short names stay as aliases
    z = cmd.zenoh(parse([cmd.name, "--connect", "tcp/10.0.0.4:1", "--listen", "tcp/127.0.0.1:2",
                         "--mode", "client"]))
    assert (z.connect, z.listen, z.mode) == (("tcp/10.0.0.4:1",), ("tcp/127.0.0.1:2",), "client")


@pytest.mark.parametrize("cmd", COMMANDS, ids=IDS)
@pytest.mark.parametrize("layer", ["file", "environment", "options", "unknown variable"])
def test_bad_key_in_each_layer_exits_2_naming_it(
    cmd: Command, layer: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    argv = [cmd.name, *cmd.base_args]
    if layer == "file":
        cfg = tmp_path / "c.toml"
        cfg.write_text("[zenoh]\nlisten_on = []\n", encoding="utf-8")
        argv += ["--config", str(cfg)]
        names = ["zenoh.listen_on"]
    elif layer == "environment":
        monkeypatch.setenv(f"{cmd.env_prefix}ZENOH_MODE", "bogus")
        names = ["zenoh.mode", f"{cmd.env_prefix}ZENOH_MODE"]
    elif layer == "options":
        argv += [cmd.connect_option, "foo:bar"]
        names = ["zenoh.connect", "foo:bar"]
    else:
        monkeypatch.setenv(f"{cmd.env_prefix}ZENOH_CONECT", "tcp/127.0.0.1:1")
        names = [f"{cmd.env_prefix}ZENOH_CONECT"]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    for name in names:
        assert name in err


def test_solver_station_tables_between_file_defaults_and_environment(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from groundstation.solve.service import load_service_settings

    cfg = tmp_path / "solver.toml"
    cfg.write_text('interp = "linear"\nepsg = 25832\n'
                   '[stations.alpha]\nbase = "b.ubx"\n'
                   'base_xyz = [4201000, 180000, 4779000]\ninterp = "spline"\n',
                   encoding="utf-8")
    s = load_service_settings(cfg, {})
    alpha = s.for_station("alpha")
    assert (alpha.interp, alpha.epsg, s.default.interp) == ("spline", 25832, "linear")
    monkeypatch.setenv("GROUNDSTATION_SOLVER_INTERP", "smoother")
    monkeypatch.setenv("GROUNDSTATION_SOLVER_QUEUE_SIZE", "3")
    s = load_service_settings(cfg, {})
    assert s.for_station("alpha").interp == "smoother" and s.queue_size == 3
    s = load_service_settings(cfg, {"interp": "linear"})
    assert s.for_station("alpha").interp == "linear"
    monkeypatch.setenv("GROUNDSTATION_SOLVER_MAX_GAP_S", "nan")
    with pytest.raises(ConfigError) as info:
        load_service_settings(cfg, {})
    assert info.value.key == "max_gap_s" and "GROUNDSTATION_SOLVER_MAX_GAP_S" in str(info.value)


@pytest.mark.parametrize(("argv", "key"), [
    (["run", "--port", "/dev/x", "--duration", "nan"], "duration_s"),
    (["run", "--port", "/dev/x", "--baud", "fast"], "source.baud"),
    (["watch", "--duration", "inf"], "duration_s"),
    (["dashboard", "--port", "70000"], "port"),
    (["solver", "--duration", "nan"], "duration"),
])
def test_bad_option_values_exit_2(argv: list[str], key: str,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(argv) == 2
    assert f"{key}:" in capsys.readouterr().err


@pytest.mark.parametrize("kind", ["directory", "fifo", "not utf-8"])
def test_config_file_that_cannot_be_read_exits_2(
    kind: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import os

    path = tmp_path / "c.toml"
    if kind == "directory":
        path.mkdir()
    elif kind == "fifo":
        os.mkfifo(path)
    else:
        path.write_bytes(b"station = '\xff'\n")
    for command in ("run", "solver", "watch", "dashboard"):
        assert cli.main([command, "--config", str(path)]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and "config:" in err
