"""Engine options: each engine's own table, checks that name the key, .conf files, precedence."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from groundstation.cli import main
from groundstation.errors import ConfigError
from groundstation.solve import engine
from groundstation.solve.engine import options as eo
from groundstation.solve.engine.b34_table import SYSOPTS_B34
from groundstation.solve.engine.demo5 import Demo5Engine
from groundstation.solve.engine.rnx2rtkp import TABLE_B34, Rnx2rtkpEngine

BASE = (3774696.5547, -596647.9083, 5089485.6511)


@pytest.fixture(scope="module")
def demo5_table() -> eo.OptionTable:
    return Demo5Engine().option_table()


def test_demo5_table_is_read_from_the_engine(demo5_table: eo.OptionTable) -> None:
    # demo5-only AR controls are there, b34 lacks them; the worker reports RTKLIB-EX.
    for key in ("pos2-arfilter", "pos2-minfixsats", "pos2-varholdamb", "pos2-mindropsats"):
        assert key in demo5_table and key not in TABLE_B34
    spec = demo5_table.get("pos1-soltype")
    assert spec is not None and spec.choices()["combined"] == 2
    assert "EX" in Demo5Engine().version() and "pyrtklib5" in Demo5Engine().version()
    assert "pos1-ephem" not in demo5_table and "pos1-ephem" not in TABLE_B34


def test_defaults_pass_their_own_engine_tables(demo5_table: eo.OptionTable) -> None:
    assert eo.check_options(demo5_table, eo.UBLOX_L1_5HZ, "default") == eo.UBLOX_L1_5HZ
    assert eo.check_options(TABLE_B34, eo.B34_L1_KINEMATIC, "default")
    # demo5's defaults use keys b34 does not have: each engine is checked against its own table.
    with pytest.raises(ConfigError, match="pos2-arfilter"):
        eo.check_options(TABLE_B34, eo.UBLOX_L1_5HZ, "default")


@pytest.mark.parametrize(
    ("key", "value", "match"),
    [
        ("pos1-ephem", "brdc", "pos1-ephem: not an option of demo5"),
        ("pos2-arthres", "three", "pos2-arthres: expected a number"),
        ("pos2-arthres", "nan", "pos2-arthres: expected a finite number"),
        ("pos2-arlockcnt", "5.5", "pos2-arlockcnt: expected an integer"),
        ("pos1-posmode", "kinematik", "pos1-posmode: 'kinematik' is not one of 0:single"),
        ("pos1-soltype", "7", "pos1-soltype: '7' is not one of"),
        ("pos1-navsys", "128", "pos1-navsys: 128 is not a sum of"),
        ("elmask", "15", "did you mean pos1-elmask"),  # RTKLIB would match it as a substring
    ],
)
def test_bad_option_names_the_key(
    demo5_table: eo.OptionTable, key: str, value: str, match: str
) -> None:
    with pytest.raises(ConfigError, match=match) as err:
        eo.check_option(demo5_table, key, value, "--rtk-opt")
    assert key in err.value.key


def test_good_values_by_name_or_number(demo5_table: eo.OptionTable) -> None:
    assert eo.check_option(demo5_table, "pos1-posmode", " static ", "") == "static"
    assert eo.check_option(demo5_table, "pos1-posmode", "3", "") == "3"
    assert eo.check_option(demo5_table, "pos1-navsys", "45", "") == "45"
    assert eo.check_option(demo5_table, "pos1-exclsats", "G05 R10", "") == "G05 R10"


def test_conf_file_lines_and_errors(tmp_path: Path, demo5_table: eo.OptionTable) -> None:
    conf = tmp_path / "my.conf"
    conf.write_text(
        "# exported from RTKPOST\n\npos1-posmode       =static     # (0:single,...)\n"
        "pos2-arthres =2.5\n"
    )
    assert eo.read_conf(conf, demo5_table) == {"pos1-posmode": "static", "pos2-arthres": "2.5"}
    conf.write_text("pos1-posmode =static\npos2-arthres =abc\n")
    with pytest.raises(ConfigError, match=r"my.conf:2 pos2-arthres: expected a number"):
        eo.read_conf(conf, demo5_table)
    conf.write_text("pos1-posmode static\n")
    with pytest.raises(ConfigError, match=r"my.conf:1"):
        eo.read_conf(conf, demo5_table)
    with pytest.raises(ConfigError, match="--rtk-conf"):
        eo.read_conf(tmp_path / "missing.conf", demo5_table)


def test_precedence_defaults_conf_base_overrides(tmp_path: Path) -> None:
    conf = tmp_path / "c.conf"
    conf.write_text("pos2-arthres =2\nant2-pos1 =1\nout-solformat =llh\npos1-elmask =10\n")
    opts, notes = engine.resolve_options(
        Demo5Engine(), BASE, conf, {"pos1-elmask": "20", "pos2-armode": "continuous"}
    )
    assert opts["pos2-arthres"] == "2"  # conf over the default (3)
    assert opts["ant2-pos1"] == f"{BASE[0]:.4f}"  # --base-xyz over the conf
    assert opts["pos1-elmask"] == "20" and opts["pos2-armode"] == "continuous"  # --rtk-opt last
    assert opts["out-solformat"] == "xyz"  # the reader's need wins, and says so
    assert notes == ["option out-solformat=llh replaced by xyz (our reader needs it)"]
    assert opts["pos1-soltype"] == "combined"  # untouched defaults stay


def test_cli_rejects_unknown_option_and_bad_value_with_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    flight, base = tmp_path / "f.ubx", tmp_path / "b.obs"
    flight.write_bytes(b"")
    base.write_text("")
    common = ["solve", "--no-pdf",
              str(flight), "--base", str(base), "--base-xyz", "4201000,180000,4779000",
              "--out", str(tmp_path / "out"), "--no-progress"]
    assert main([*common, "--rtk-opt", "pos1-ephem=brdc"]) == 2
    assert "pos1-ephem" in capsys.readouterr().err
    assert main([*common, "--rtk-opt", "pos2-arthres"]) == 2
    assert "--rtk-opt" in capsys.readouterr().err
    conf = tmp_path / "x.conf"
    conf.write_text("pos1-posmode =kinematic\npos1-frequency =l9\n")
    assert main([*common, "--rtk-conf", str(conf)]) == 2
    assert "x.conf:2 pos1-frequency" in capsys.readouterr().err
    assert main([*common, "--engine", "nope"]) == 2
    assert "--engine" in capsys.readouterr().err
    # b34 has no demo5 AR controls: the same key is fine for demo5, an error for rnx2rtkp.
    assert main([*common, "--engine", "rnx2rtkp", "--rtk-opt", "pos2-arfilter=on"]) == 2
    assert "pos2-arfilter: not an option of rnx2rtkp" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.skipif(shutil.which("rnx2rtkp") is None or shutil.which("strings") is None,
                    reason="rnx2rtkp or binutils' strings not installed")
def test_b34_table_matches_the_installed_binary() -> None:
    exe = shutil.which("rnx2rtkp")
    assert exe is not None
    text = subprocess.run(["strings", "-n", "3", exe], capture_output=True, text=True,
                          check=True).stdout
    in_binary = set(re.findall(r"^(?:pos1|pos2|out|stats|ant1|ant2|misc|file)-\w+$", text,
                               re.MULTILINE))
    assert in_binary == {name for name, _, _ in SYSOPTS_B34}
    assert Rnx2rtkpEngine().option_table() is TABLE_B34
