"""The systemd units and the udev rule: required directives, and ``systemd-analyze verify``."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

SYSTEMD = Path(__file__).resolve().parents[2] / "systemd"
UNITS = ("groundstation.service", "groundstation-solver.service")
COMMON = {
    "User": "groundstation",
    "Restart": "on-failure",
    "ProtectSystem": "strict",
    "ReadWritePaths": "/var/lib/groundstation/flights",
    "NoNewPrivileges": "yes",
    "PrivateTmp": "yes",
    "ProtectHome": "yes",
}


def _service(name: str) -> dict[str, list[str]]:
    """``[Service]`` directives, each with all its values (units may repeat a key)."""
    out: dict[str, list[str]] = {}
    section = ""
    for line in (SYSTEMD / name).read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        if line.startswith("["):
            section = line
            continue
        if section == "[Service]":
            key, _, value = line.partition("=")
            out.setdefault(key, []).append(value)
    return out


@pytest.mark.parametrize("name", UNITS)
def test_required_directives(name: str) -> None:
    service = _service(name)
    for key, value in COMMON.items():
        assert service.get(key) == [value], f"{name}: {key}"
    assert service["CapabilityBoundingSet"] == [""]  # no capabilities at all
    assert "AF_INET" in service["RestrictAddressFamilies"][0]  # Zenoh on loopback


def test_daemon_unit() -> None:
    service = _service("groundstation.service")
    assert service["ExecStart"] == [
        "/usr/local/bin/groundstation run --config /etc/groundstation/groundstation.toml"
    ]
    assert service["SupplementaryGroups"] == ["dialout"]
    # The serial device must stay reachable under the device policy.
    assert service.get("PrivateDevices", ["no"]) == ["no"]
    assert "char-ttyUSB rw" in service["DeviceAllow"]
    assert service["KillSignal"] == ["SIGTERM"]


def test_solver_unit() -> None:
    service = _service("groundstation-solver.service")
    assert service["ExecStart"][0].startswith("/usr/local/bin/groundstation solver ")
    assert service["PrivateDevices"] == ["yes"]


def test_udev_rule() -> None:
    rules = [
        line for line in (SYSTEMD / "99-wi232.rules").read_text().splitlines()
        if line.strip() and not line.startswith("#")
    ]
    assert len(rules) == 1
    rule = rules[0]
    for part in ('SUBSYSTEM=="tty"', 'ATTRS{idVendor}=="0403"', 'ATTRS{idProduct}=="6001"',
                 'SYMLINK+="wi232"', 'GROUP="dialout"', 'MODE="0660"'):
        assert part in rule


@pytest.mark.parametrize("name", UNITS)
def test_systemd_analyze_verify(name: str, tmp_path: Path) -> None:
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        pytest.skip("systemd-analyze is not installed (Debian package 'systemd')")
    # verify insists that ExecStart exists: point it at this interpreter, keep everything else.
    text = (SYSTEMD / name).read_text().replace("/usr/local/bin/groundstation", sys.executable)
    unit = tmp_path / name
    unit.write_text(text)
    proc = subprocess.run(
        [analyze, "verify", "--man=no", str(unit)],
        capture_output=True, text=True, timeout=60, check=False,
    )
    # verify exits 0 on unknown keys and bad values too; only silence means clean.
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "" and proc.stderr.strip() == "", proc.stderr
