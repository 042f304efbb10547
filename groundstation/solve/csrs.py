"""The base position from an NRCan CSRS-PPP summary (``.sum``), for ``solve --base-position``.

The summary gives the estimated position as three records, one per coordinate::

    POS LAT <frame> <yy:doy:sod>  <a priori d m s>  <estimated d m s>  <difference m>  <sigma m>
    POS LON <frame> <yy:doy:sod>  <a priori d m s>  <estimated d m s>  <difference m>  <sigma m>
    POS HGT <frame> <yy:doy:sod>  <a priori m>      <estimated m>      <difference m>  <sigma m>

once in the global frame (``IGS14``, ``IGb14``, ``IGS20``, ``IGc20``, ``ITRF2014``...) and, for a
Canadian solution, again in ``NAD83(CSRS)``. The global frame is what the broadcast orbits and
WGS84 (G1762 onwards) agree with at the centimetre; NAD83 differs by metres and is refused when
it is the only one. CSRS-PPP states its sigmas at 95 % confidence: divided by 1.96 for one
sigma. The epoch (``yy:doy:sod``) is the coordinates' epoch, said with the position.

Records are read from the end of the line (sigma, difference, then the estimate), so the
a priori value's layout does not matter.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

from groundstation.errors import ConfigError
from groundstation.geodesy import llh_to_ecef

OPTION = "--base-position"
SIGMA_95_TO_1 = 1.0 / 1.96
"""CSRS-PPP's sigmas are at 95 % confidence (a normal error's 1.96 sigma)."""
GLOBAL_FRAME = re.compile(r"^(IG[A-Za-z]?\d{2}|ITRF\d{2,4})$")
_EPOCH = re.compile(r"^(\d{2}):(\d{3}):(\d+)$")


def looks_like_sum(head: bytes) -> bool:
    """Whether a file's first bytes are a CSRS-PPP summary's (its ``POS LAT`` record, or its
    header naming the service)."""
    return b"POS LAT" in head or b"CSRS-PPP" in head


def _dms(tokens: list[str]) -> float:
    """Degrees, minutes, seconds (the sign on the degrees, ``-0`` included) in degrees."""
    d, m, s = tokens
    sign = -1.0 if d.strip().startswith("-") else 1.0
    return sign * (abs(float(d)) + float(m) / 60.0 + float(s) / 3600.0)


def read_sum(path: Path, text: str) -> tuple[tuple[float, float, float],
                                             tuple[float, float, float], str]:
    """The global-frame position in a CSRS-PPP summary: (ECEF, sigma east/north/up at one
    sigma, how it was given).

    Raises:
        ConfigError: naming ``--base-position``: no complete global-frame position in it.
    """
    found: dict[str, dict[str, tuple[float, float, str]]] = {}
    for line in text.splitlines():
        t = line.split()
        if len(t) < 8 or t[0] != "POS" or t[1] not in ("LAT", "LON", "HGT"):
            continue
        try:
            sigma = float(t[-1])
            value = (_dms(t[-5:-2]) if t[1] != "HGT" else float(t[-3]))
        except ValueError:
            continue
        found.setdefault(t[2], {})[t[1]] = (value, sigma, t[3])
    frames = [f for f, rec in found.items() if GLOBAL_FRAME.match(f) and len(rec) == 3]
    if not frames:
        other = ", ".join(sorted(found)) or "none"
        raise ConfigError(OPTION, (
            f"{path}: no position in a global frame (IGS/ITRF) in this CSRS-PPP summary "
            f"(frames found: {other}); NAD83(CSRS) differs from WGS84 by metres: ask CSRS-PPP "
            "for the ITRF result, or give --base-llh in WGS84"))
    frame = frames[0]
    rec = found[frame]
    lat, sd_n, epoch = rec["LAT"]
    lon, sd_e, _ = rec["LON"]
    h, sd_u, _ = rec["HGT"]
    if not (abs(lat) <= 90 and abs(lon) <= 360 and -1000 < h < 10000) or not all(
            math.isfinite(v) and v >= 0 for v in (sd_e, sd_n, sd_u)):
        raise ConfigError(OPTION, f"{path}: the CSRS-PPP position is not a place on the Earth "
                          f"(lat {lat}, lon {lon}, h {h})")
    x, y, z = llh_to_ecef(lat, lon, h)
    sd = (sd_e * SIGMA_95_TO_1, sd_n * SIGMA_95_TO_1, sd_u * SIGMA_95_TO_1)
    how = (f"from {path.name} (NRCan CSRS-PPP, {frame}{_epoch_text(epoch)}, its 95 % sigmas "
           "divided by 1.96 for one sigma; a PPP from L1-only data is good to decimetres at "
           "best)")
    return (x, y, z), sd, how


def _epoch_text(token: str) -> str:
    """``yy:doy:sod`` as a decimal year, or nothing when it is not one."""
    m = _EPOCH.match(token)
    if m is None:
        return ""
    yy, doy, sod = int(m[1]), int(m[2]), float(m[3])
    year = 2000 + yy if yy < 80 else 1900 + yy
    days = 366 if year % 4 == 0 and (year % 100 != 0 or year % 400 == 0) else 365
    return f", epoch {year + (doy - 1 + sod / 86400.0) / days:.2f}"
