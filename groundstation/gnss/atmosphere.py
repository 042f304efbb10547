"""Signal delay models: Klobuchar ionosphere (IS-GPS-200 20.3.3.5.2.5), the simulator's continuous
ionosphere of the same shape, Saastamoinen troposphere."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from groundstation.gnss.orbit import C_M_S

FloatArray = NDArray[np.float64]

KLOBUCHAR_ALPHA_DEFAULT = (1.1175870895385742e-08, 7.450580596923828e-09,
                           -5.960464477539063e-08, -5.960464477539063e-08)
KLOBUCHAR_BETA_DEFAULT = (90112.0, 0.0, -196608.0, -65536.0)


def _series_daytime(amp: FloatArray, x: FloatArray) -> FloatArray:
    """The broadcast model's daytime term: the cosine's 4th-order series, cut off at
    ``|x| = 1.57`` as IS-GPS-200 has it."""
    return np.where(np.abs(x) < 1.57, amp * (1.0 - x * x / 2.0 + x**4 / 24.0), 0.0)


def _cosine_daytime(amp: FloatArray, x: FloatArray) -> FloatArray:
    """The daytime term of a continuous ionosphere: the cosine itself, zero where it is."""
    return np.where(np.abs(x) < np.pi / 2, amp * np.cos(x), 0.0)


def _klobuchar_shaped_delay_m(
    daytime: Callable[[FloatArray, FloatArray], FloatArray],
    alpha: tuple[float, float, float, float],
    beta: tuple[float, float, float, float],
    lat_deg: float,
    lon_deg: float,
    az_deg: ArrayLike,
    el_deg: ArrayLike,
    tow_s: ArrayLike,
) -> FloatArray:
    """L1 ionospheric group delay (m) of the broadcast model's shape, per IS-GPS-200
    20.3.3.5.2.5: pierce point, obliquity factor, daytime amplitude and period as the standard
    has them; the night-time constant 5 ns plus ``daytime(amp, x)`` (``amp`` in s, ``x`` the
    phase in rad), times the obliquity."""
    phi_u = lat_deg / 180.0
    lam_u = lon_deg / 180.0
    az = np.radians(np.asarray(az_deg, dtype=np.float64))
    e = np.asarray(el_deg, dtype=np.float64) / 180.0
    psi = 0.0137 / (e + 0.11) - 0.022
    phi_i = np.clip(phi_u + psi * np.cos(az), -0.416, 0.416)
    lam_i = lam_u + psi * np.sin(az) / np.cos(phi_i * np.pi)
    phi_m = phi_i + 0.064 * np.cos((lam_i - 1.617) * np.pi)
    t = np.mod(4.32e4 * lam_i + np.asarray(tow_s, dtype=np.float64), 86400.0)
    f = 1.0 + 16.0 * (0.53 - e) ** 3
    amp = np.maximum(sum(a * phi_m**n for n, a in enumerate(alpha)), 0.0)
    per = np.maximum(sum(b * phi_m**n for n, b in enumerate(beta)), 72000.0)
    x = 2.0 * np.pi * (t - 50400.0) / per
    day = daytime(np.asarray(amp, dtype=np.float64), np.asarray(x, dtype=np.float64))
    return np.asarray(f * (5e-9 + day) * C_M_S, dtype=np.float64)


def klobuchar_delay_m(
    alpha: tuple[float, float, float, float],
    beta: tuple[float, float, float, float],
    lat_deg: float,
    lon_deg: float,
    az_deg: ArrayLike,
    el_deg: ArrayLike,
    tow_s: ArrayLike,
) -> FloatArray:
    """L1 ionospheric group delay (m) of the broadcast model, per IS-GPS-200.

    As the standard has it, the daytime cosine is a 4th-order series cut off at ``|x| = 1.57``,
    where it still has 2 % of its amplitude: the delay steps there by up to several centimetres.
    That is right for a receiver's correction model and wrong for a "true" ionosphere (see
    :func:`smooth_ionosphere_delay_m`).
    """
    return _klobuchar_shaped_delay_m(
        _series_daytime, alpha, beta, lat_deg, lon_deg, az_deg, el_deg, tow_s)


def smooth_ionosphere_delay_m(
    alpha: tuple[float, float, float, float],
    beta: tuple[float, float, float, float],
    lat_deg: float,
    lon_deg: float,
    az_deg: ArrayLike,
    el_deg: ArrayLike,
    tow_s: ArrayLike,
) -> FloatArray:
    """L1 ionospheric group delay (m) of a continuous ionosphere shaped like the broadcast model.

    The simulator's "true" ionosphere. A real ionosphere is smooth in time and space; the
    broadcast model's series steps by centimetres at its cut-off, and two receivers a few hundred
    metres apart cross that step seconds apart, which puts a false jump into their double
    differences. Here the daytime term is the cosine itself, ``amp * cos(x)``, which reaches zero
    exactly where the night-time constant takes over: the delay is continuous everywhere (its
    slope changes there by ``amp * 2 pi / period``, a few tenths of a millimetre per second).
    Same pierce point, obliquity, amplitude and period as :func:`klobuchar_delay_m`; the two
    differ by at most 2 % of the daytime delay (the series' remainder near the cut-off).
    """
    return _klobuchar_shaped_delay_m(
        _cosine_daytime, alpha, beta, lat_deg, lon_deg, az_deg, el_deg, tow_s)


def saastamoinen_delay_m(
    lat_deg: float, h_m: ArrayLike, el_deg: ArrayLike, humidity: float = 0.7
) -> FloatArray:
    """Tropospheric delay (m): Saastamoinen with a standard atmosphere (as RTKLIB's model).

    ``h_m`` (ellipsoidal height) and ``el_deg`` may be arrays of the same shape.
    """
    el = np.radians(np.asarray(el_deg, dtype=np.float64))
    h = np.maximum(np.asarray(h_m, dtype=np.float64), 0.0)
    pres = 1013.25 * (1.0 - 2.2557e-5 * h) ** 5.2568
    temp = 15.0 - 6.5e-3 * h + 273.16
    e_w = 6.108 * humidity * np.exp((17.15 * temp - 4684.0) / (temp - 38.45))
    z = np.pi / 2.0 - np.maximum(el, np.radians(1.0))
    trph = 0.0022768 * pres / (
        1.0 - 0.00266 * np.cos(2.0 * np.radians(lat_deg)) - 0.00028 * h / 1e3
    ) / np.cos(z)
    trpw = 0.002277 * (1255.0 / temp + 0.05) * e_w / np.cos(z)
    return np.asarray(trph + trpw, dtype=np.float64)
