"""``run --port`` naming a device that does not exist: one line, with the nearest existing
serial devices as a hint, before anything starts (the whole run: tests/integration/
test_liveness.py, test_missing_port_at_start_is_one_line_and_nothing_else)."""

from __future__ import annotations

from pathlib import Path

from groundstation.commands.run import missing_port_line, port_problem


def test_the_line_names_the_nearest_existing_devices() -> None:
    line = missing_port_line("/dev/ttyUSB9", ["/dev/ttyACM0", "/dev/ttyUSB0", "/dev/ttyAMA0"])
    assert line.startswith("groundstation run: error: /dev/ttyUSB9 does not exist (existing: "
                           "/dev/ttyUSB0, ")
    assert "\n" not in line and "plug the receiver in or name its device with --port" in line


def test_without_any_serial_device_the_line_says_where_it_looked() -> None:
    line = missing_port_line("/dev/ttyUSB9", [])
    assert "no serial device present: none of /dev/ttyUSB*" in line


def test_a_missing_device_is_a_problem_an_existing_one_is_not(tmp_path: Path) -> None:
    gone = str(tmp_path / "ttyUSB9")
    assert port_problem(gone) == missing_port_line(gone)
    assert port_problem("/dev/null") is None  # a character device this user may open
