"""Receiver profiles: the shipped ones build, and every kind of mistake names its key."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from pyubx2 import SET, UBXReader
from pyubx2.ubxtypes_configdb import UBX_CONFIG_DATABASE

from groundstation.errors import ConfigError
from groundstation.ubx.cfg import (
    available_profiles,
    build_message,
    find_profile,
    load_profile,
    parse_profile,
    settable_fields,
)

SHIPPED = ("lea6t-5hz", "m8t-raw", "f9p-raw")


def test_shipped_profiles_are_found() -> None:
    assert set(SHIPPED) <= set(available_profiles())


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_profile_frames_parse_back(name: str) -> None:
    profile = load_profile(name)
    assert profile.name == name and profile.receiver and profile.description
    for m in profile.messages:
        parsed = UBXReader.parse(m.frame, msgmode=SET)
        assert parsed.identity == m.name
        assert (m.cls, m.id) == (m.frame[2], m.frame[3])
    assert profile.messages[0].uart1_baud is not None  # each profile sets UART1 first


def test_lea6t_enables_the_messages_the_project_needs() -> None:
    msgs = load_profile("lea6t-5hz").messages
    enabled = {}
    for m in msgs:
        p = UBXReader.parse(m.frame, msgmode=SET)
        if m.name == "CFG-MSG":
            enabled[bytes(m.frame[6:8])] = p.rateUART1
    assert enabled == {
        b"\x02\x10": 1, b"\x02\x11": 1, b"\x0d\x03": 1, b"\x01\x06": 1, b"\x01\x30": 5,
    }
    rate = UBXReader.parse(msgs[1].frame, msgmode=SET)
    assert (rate.measRate, rate.navRate, rate.timeRef) == (200, 1, 1)
    assert msgs[-1].name == "CFG-CFG"


def test_f9p_keys() -> None:
    msgs = load_profile("f9p-raw").messages
    assert [m.name for m in msgs] == ["CFG-VALSET", "CFG-VALSET"]
    assert msgs[0].uart1_baud == 115200 and msgs[1].uart1_baud is None
    p = UBXReader.parse(msgs[1].frame, msgmode=SET)
    assert p.CFG_MSGOUT_UBX_RXM_RAWX_UART1 == 1 and p.CFG_RATE_MEAS == 200
    assert (p.ram, p.bbr, p.flash) == (1, 1, 1)


def test_bit_field_members_are_settable() -> None:
    fields = settable_fields("CFG-PRT")
    assert fields["baudRate"] == "U004"
    assert fields["inUBX"] == "b001" and fields["pin"] == "b005"
    assert "UARTmode_bit" not in fields


def test_baud_only_for_uart1_in_ram() -> None:
    usb = build_message({"name": "CFG-PRT", "fields": {"portID": 3, "baudRate": 115200}})
    assert usb.uart1_baud is None
    flash_only = build_message(
        {"name": "CFG-VALSET", "layers": ["flash"], "keys": {"CFG_UART1_BAUDRATE": 115200}}
    )
    assert flash_only.uart1_baud is None


def test_find_profile_by_path(tmp_path: Path) -> None:
    p = tmp_path / "mine.toml"
    p.write_text('[[messages]]\nname = "CFG-RATE"\nfields = { measRate = 1000 }\n')
    assert find_profile(str(p)) == p
    assert load_profile(str(p)).name == "mine"
    assert load_profile("mine", [tmp_path]).messages[0].name == "CFG-RATE"


def _error(data: dict[str, Any]) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        parse_profile(data, Path("x.toml"))
    return info.value


def _msg(**spec: Any) -> dict[str, Any]:
    return {"messages": [spec]}


@pytest.mark.parametrize(
    ("data", "key", "text"),
    [
        ({"messages": []}, "messages", "non-empty"),
        ({"messages": [], "nmae": "x"}, "nmae", "unknown key"),
        ({"messages": ["CFG-MSG"]}, "messages[0]", "must be a table"),
        (_msg(fields={}), "messages[0].name", "missing message name"),
        (_msg(name="NAV-PVT"), "messages[0].name", "not a CFG message"),
        (_msg(name="CFG-NOPE"), "messages[0].name", "not a CFG message"),
        (_msg(name="CFG-MSG", feilds={}), "messages[0].feilds", "unknown key"),
        (_msg(name="CFG-MSG", fields={"rateUART": 1}), "messages[0].fields.rateUART",
         "has no field 'rateUART'"),
        (_msg(name="CFG-MSG", fields={"rateUART1": 256}), "messages[0].fields.rateUART1",
         "does not fit"),
        (_msg(name="CFG-MSG", fields={"rateUART1": "1"}), "messages[0].fields.rateUART1",
         "expected an integer"),
        (_msg(name="CFG-MSG", fields={"rateUART1": True}), "messages[0].fields.rateUART1",
         "expected an integer"),
        (_msg(name="CFG-PRT", fields={"pin": 32}), "messages[0].fields.pin", "does not fit"),
        (_msg(name="CFG-TP5", fields={"antCableDelay": -40000}),
         "messages[0].fields.antCableDelay", "does not fit"),
        (_msg(name="CFG-VALSET", keys={"CFG_NOPE": 1}), "messages[0].keys.CFG_NOPE",
         "not a configuration key"),
        (_msg(name="CFG-VALSET", keys={"CFG_UART1OUTPROT_NMEA": 0}),
         "messages[0].keys.CFG_UART1OUTPROT_NMEA", "expected true or false"),
        (_msg(name="CFG-VALSET", layers=["rom"], keys={"CFG_RATE_MEAS": 200}),
         "messages[0].layers", "unknown layer"),
        (_msg(name="CFG-VALSET", keys={}), "messages[0].keys", "non-empty"),
        (_msg(name="CFG-VALSET", fields={"x": 1}), "messages[0].fields", "unknown key"),
    ],
)
def test_validation_names_the_key(data: dict[str, Any], key: str, text: str) -> None:
    err = _error(data)
    assert err.key == key
    assert text in err.message


def test_valset_key_limit() -> None:
    keys = {f"CFG_MSGOUT_UBX_{n}_UART1": 1 for n in (
        "NAV_PVT", "NAV_SAT", "RXM_RAWX", "RXM_SFRBX", "TIM_TM2")}
    build_message({"name": "CFG-VALSET", "keys": keys})  # fine
    many = dict.fromkeys(list(UBX_CONFIG_DATABASE)[:65], 1)
    with pytest.raises(ConfigError, match="at most 64"):
        build_message({"name": "CFG-VALSET", "keys": many})


def test_unknown_profile_lists_known(tmp_path: Path) -> None:
    (tmp_path / "a.toml").write_text("")
    with pytest.raises(ConfigError) as info:
        find_profile("b", [tmp_path])
    assert info.value.key == "profile"
    assert "unknown profile 'b' (known: a;" in info.value.message


def test_invalid_toml(tmp_path: Path) -> None:
    (tmp_path / "broken.toml").write_text("[[messages]\n")
    with pytest.raises(ConfigError, match="invalid TOML"):
        load_profile("broken", [tmp_path])
