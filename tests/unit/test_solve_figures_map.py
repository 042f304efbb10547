"""The report's map drawn from the base: the frame is the flight's whatever the base's
distance, the base drawn and named only where it falls within it, and the map of a flight
moved with its base unchanged (what lets a re-base keep it)."""

from __future__ import annotations

import re

import numpy as np

from groundstation.solve import figures

T0 = 2022 * 604_800 * 10**9


def _map(offset_m: float, base_at: tuple[float, float]) -> str:
    t = T0 + np.arange(200, dtype=np.int64) * 200_000_000
    x = 500_000.0 + offset_m + 40.0 * np.cos(np.arange(200) / 30.0)
    y = 5_538_000.0 + offset_m + 25.0 * np.sin(np.arange(200) / 30.0)
    return figures.trajectory(
        x, y, np.ones(200, np.int64), t, x[::20], y[::20], max_gap_s=1.0,
        crs="EPSG:32629 WGS 84 / UTM zone 29N", projected=True,
        cam_grade=["fixed"] * 10, origin=(base_at[0] + offset_m, base_at[1] + offset_m))


def _ticks(svg: str) -> list[str]:
    return re.findall(r">(−?\d+)\n?</text>", svg)


def test_the_map_is_drawn_from_the_base_and_keeps_the_flights_frame() -> None:
    near = _map(0.0, (500_010.0, 5_538_005.0))
    assert "Easting from the base (m)" in near and ">base<" in near.replace("\n", "")
    far = _map(0.0, (497_000.0, 5_541_000.0))  # 4 km off: not in the frame, not drawn
    assert ">base<" not in far.replace("\n", "")
    ticks = [int(v.replace("−", "-")) for v in _ticks(far)]
    assert ticks and min(abs(v) for v in ticks) > 2000  # from the base, the flight's frame
    # the flight and its base moved alike by 1.3 km: the same picture
    assert _map(1300.0, (500_010.0, 5_538_005.0)).replace("−", "-") == near.replace("−", "-")
