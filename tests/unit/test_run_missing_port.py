"""``run --port`` naming a device that does not exist: one line at once, with the nearest
existing serial devices as a hint."""

from __future__ import annotations

from groundstation.commands.run import missing_port_line


def test_the_line_names_the_nearest_existing_devices() -> None:
    line = missing_port_line("/dev/ttyUSB9", ["/dev/ttyACM0", "/dev/ttyUSB0", "/dev/ttyAMA0"])
    assert line.startswith("groundstation run: /dev/ttyUSB9 does not exist (existing: "
                           "/dev/ttyUSB0, ")
    assert "\n" not in line and "waiting for it" in line


def test_without_any_serial_device_the_line_says_where_it_looked() -> None:
    line = missing_port_line("/dev/ttyUSB9", [])
    assert "no serial device present: none of /dev/ttyUSB*" in line
