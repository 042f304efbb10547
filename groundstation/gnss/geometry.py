"""Satellite positions and clocks at each measurement's transmission time, and ranges from them.

One implementation for everything after the recording that needs the geometry of a receiver's
measurements: the phase conditioning (jumps across radio gaps) and the integrity stage (phase
residuals of a trajectory). Vectorised over epochs x satellites; GPS broadcast ephemerides.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from groundstation.gnss.ephemeris import BroadcastEphemeris
from groundstation.gnss.orbit import C_M_S, rotate_earth, sat_state, toe_gps_ns

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

MAX_EPHEMERIS_AGE_S = 4 * 3600.0
"""A broadcast orbit is used at most this far from its reference time (its fit interval)."""


class SatGeometry:
    """Satellite positions and clocks for every (epoch, satellite) with a pseudorange.

    Attributes:
        pos: (n_ep, n_sv, 3) ECEF position at transmission time, NaN where unknown.
        clk_m: (n_ep, n_sv) satellite clock offset times c [m], NaN where unknown.
        pr: (n_ep, n_sv) pseudoranges [m] (0 or NaN: none).
    """

    def __init__(
        self, t_ns: IntArray, svs: Sequence[int], pr: FloatArray,
        ephs: Sequence[BroadcastEphemeris], approx_ecef_m: tuple[float, float, float] = (0, 0, 0),
    ) -> None:
        n_ep, n_sv = pr.shape
        self.t_ns = t_ns
        self.pos = np.full((n_ep, n_sv, 3), np.nan)
        self.clk_m = np.full((n_ep, n_sv), np.nan)
        self.pr = pr
        by_sv: dict[int, list[BroadcastEphemeris]] = {}
        for eph in ephs:
            if eph.health == 0:
                by_sv.setdefault(eph.sv, []).append(eph)
        for j, sv in enumerate(svs):
            cands = by_sv.get(sv)
            rows = np.flatnonzero(np.nan_to_num(pr[:, j]) > 0)
            if not cands or rows.size == 0:
                continue
            t_tx = t_ns[rows] - np.round(pr[rows, j] / C_M_S * 1e9).astype(np.int64)
            toes = np.array([toe_gps_ns(x) for x in cands], dtype=np.int64)
            dist = np.abs(t_tx[:, None] - toes[None, :])
            pick = np.argmin(dist, axis=1)
            near = dist[np.arange(rows.size), pick] <= MAX_EPHEMERIS_AGE_S * 1e9
            for k in np.unique(pick[near]).tolist():
                sel = near & (pick == k)
                st = sat_state(cands[k], (t_tx[sel] - toes[k]) / 1e9)
                self.pos[rows[sel], j] = st.pos_m
                self.clk_m[rows[sel], j] = C_M_S * st.clock_s
        self.x = np.asarray(approx_ecef_m, dtype=np.float64)
        self._spp: dict[int, FloatArray | None] = {}

    def ranges(self, e: int, sats: IntArray, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Geometric range minus satellite clock [m] and lines of sight from ``x`` at ``e``."""
        sp = self.pos[e, sats]
        d = sp - x
        tau = np.linalg.norm(d, axis=1) / C_M_S
        d = rotate_earth(sp, tau) - x
        rho = np.linalg.norm(d, axis=1)
        return rho - self.clk_m[e, sats], d / rho[:, None]

    def ranges_all(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Range minus satellite clock [m] (n_ep, n_sv) and unit lines of sight (n_ep, n_sv, 3)
        from receiver positions ``x`` ((n_ep, 3), or (3,) for a static receiver), Sagnac
        included; NaN where the satellite has no position."""
        xx = np.broadcast_to(np.asarray(x, dtype=np.float64), (self.pos.shape[0], 3))
        d = self.pos - xx[:, None, :]
        tau = np.linalg.norm(d, axis=2) / C_M_S
        d = rotate_earth(self.pos, tau) - xx[:, None, :]
        rho = np.linalg.norm(d, axis=2)
        with np.errstate(invalid="ignore"):
            los = d / rho[..., None]
        return rho - self.clk_m, los

    def position(self, e: int) -> FloatArray | None:
        """The receiver's single-point position at epoch ``e`` from its pseudoranges."""
        if e in self._spp:
            return self._spp[e]
        sats = np.flatnonzero((np.nan_to_num(self.pr[e]) > 0) & ~np.isnan(self.clk_m[e]))
        out: FloatArray | None = None
        if sats.size >= 5:
            x = self.x.copy() if np.any(self.x) else np.zeros(3)
            b = 0.0
            for _ in range(8):
                rng, u = self.ranges(e, sats, x)
                v = self.pr[e, sats] - (rng + b)
                h = np.column_stack([-u, np.ones(sats.size)])
                dx, *_ = np.linalg.lstsq(h, v, rcond=None)
                x = x + dx[:3]
                b += float(dx[3])
                if float(np.linalg.norm(dx[:3])) < 0.1:
                    out = x
                    self.x = x
                    break
        self._spp[e] = out
        return out


def elevation_deg(los: FloatArray, x: FloatArray) -> FloatArray:
    """Elevation [deg] of lines of sight ``los`` (n_ep, n_sv, 3) seen from ECEF position(s)
    ``x`` ((n_ep, 3) or (3,)): the angle above the plane normal to the ellipsoidal up."""
    xx = np.asarray(x, dtype=np.float64)
    lat = np.arctan2(xx[..., 2], np.hypot(xx[..., 0], xx[..., 1]) * (1 - 6.69437999014e-3))
    lon = np.arctan2(xx[..., 1], xx[..., 0])
    up = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=-1)
    s = los @ up if up.ndim == 1 else np.einsum("esk,ek->es", los, up)
    return np.asarray(np.degrees(np.arcsin(np.clip(s, -1.0, 1.0))), dtype=np.float64)
