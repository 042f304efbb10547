"""Carrier-phase positions during the flight: RTKLIB demo5's real-time filter (``rtkpos``,
through pyrtklib5) fed epoch by epoch with the rover's and the base's measurements.

The filter takes the same option set as the post-flight engine (``solve``'s demo5 defaults and
the base position, :func:`groundstation.solve.engine.resolve_options`, loaded through RTKLIB's
own option table), so that a live fix and a post-flight fix mean the same thing, except where
a forward filter alone needs otherwise (:data:`LIVE_OPTIONS`). Broadcast
ephemerides come from the subframes the receivers forward (RXM-SFRB / RXM-SFRBX), decoded by
our LNAV decoder (:class:`groundstation.gnss.lnav.EphemerisAssembler`) and handed to RTKLIB.

Each rover epoch is solved with the latest base epoch not after it (the base is static: an
older one serves, its age is reported as ``age_s``); a rover epoch before any base epoch, or
before four ephemerides are known, is reported with quality ``none``. Measurements carry the
phase rule's loss-of-lock bits (:mod:`groundstation.rules.phase`): a slip resets the
satellite's ambiguity in the filter, as in post-processing. After a radio gap the post-flight
conditioning's gap test flags the slips the gap hid; when fewer than four satellites kept lock
the filter restarts. An integer solution is published as ``fix`` only under the post-flight
sigma rule (every axis at most 3.3 cm), else ``float`` with the reason in ``why``
(docs/live-rtk.md).
"""

from __future__ import annotations

import dataclasses
import math
import tempfile
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from groundstation import gpstime
from groundstation.gnss import lnav
from groundstation.gnss.ephemeris import BroadcastEphemeris
from groundstation.records import LiveSolution, RawEpoch, SatObs, Subframe, TimeMark
from groundstation.rules.phase import LLI_SLIP

if TYPE_CHECKING:
    from groundstation.offline.rinex.observations import ObsSet

GNSS_GPS = 0
"""u-blox gnssId of GPS (the LEA-6T tracks GPS only)."""
SNR_UNIT = 0.001
"""RTKLIB-EX's SNR unit (dBHz per count)."""
QUALITY = {1: "fix", 2: "float", 3: "dgps", 4: "dgps", 5: "single", 6: "single"}
"""RTKLIB solution status -> the live quality (SBAS and PPP do not occur here)."""
MIN_EPHEMERIDES = 4
MAX_BASE_AGE_S = 30.0
"""A base epoch older than this is not used (``pos2-maxage``'s default)."""
GAP_CONTEXT = 8
"""Rover epochs kept before a radio gap for the gap check (the conditioning needs a few to know
the epoch interval)."""
MIN_KEPT_LOCK = 4
"""Satellites that must keep lock from one rover epoch to the next for the filter's state to
carry over (a position and a clock: four unknowns); with fewer the filter restarts."""
BASE_BUFFER = 150
"""Base epochs kept (30 s at 5 Hz): the base's stream usually arrives before the rover's."""

LIVE_OPTIONS = {"stats-prnaccelv": "0.08"}
"""Where the live filter departs from the post-flight engine's option set: its vertical
acceleration noise (m/s^2 per sqrt(s); post-flight 0.05 before the dynamics stage). The
post-flight solve combines a forward and a backward run, whose lags at a climb's or a descent's
start and end are opposite and cancel; a forward filter alone keeps its lag, which at 0.05 put
fixes 5-7 cm off at every climb's start and end, under sigmas of 1-2 cm (1-8 live fixes
beyond 3 sigma on each of 13 simulated flights, up to 13.8 cm on one). 0.08 is the stiffest
of the steps measured (0.05, 0.08, 0.1, 0.2) with no live fix beyond 3 sigma on those flights;
looser only widens the sigmas, and more integer solutions fail the 3.3 cm rule
(benchmarks/RESULTS.md, "The live filter's vertical dynamics")."""

BASE_CHECK_FIXES = 10
"""Single-point fixes of the base, one a second from its own pseudoranges, compared with the
given base coordinates once there are this many (``solve``'s check, :func:`groundstation.solve.
base.compare_base`: their mean is good to a few metres, where a wrong base shifts every live
position by its error and, kilometres off, gives none)."""
BASE_CHECK_SPACING_S = 1.0
KLOBUCHAR_DEFAULT = ((0.1118e-07, -0.7451e-08, -0.5961e-07, 0.1192e-06),
                     (0.1167e06, -0.2294e06, -0.1311e06, 0.1049e07))
"""Klobuchar alpha, beta before the receivers' subframe 4 page 18 arrives (RTKLIB's default,
the broadcast values of 2004-01-01: a mean ionosphere, good enough for a check at metres)."""


class EngineUnavailable(RuntimeError):
    """pyrtklib5 cannot be imported (the live engine needs it)."""


def _rtklib() -> Any:
    try:
        import pyrtklib5
    except ImportError as err:
        raise EngineUnavailable("the live engine needs pyrtklib5: pip install pyrtklib5"
                                ) from err
    return pyrtklib5


class LiveRtk:
    """The real-time filter of one rover against one base.

    Args:
        base_ecef_m: the base antenna's position (as ``solve`` takes it).
        overrides: engine options over the defaults (RTKLIB keys, checked).
        restart: restart the filter when the sky was lost (:meth:`_restart_if_unconnected`;
            off only to measure what it changes, ``benchmarks/bench_live_accuracy.py``).
    """

    def __init__(self, base_ecef_m: tuple[float, float, float],
                 overrides: dict[str, str] | None = None, *, restart: bool = True) -> None:
        from groundstation.solve.engine import get_engine, resolve_options
        from groundstation.solve.engine.options import conf_text
        from groundstation.solve.integrity.grade import FIXED_MAX_SIGMA_M

        self.fixed_max_sigma_m = FIXED_MAX_SIGMA_M
        """An integer solution looser than this on any axis is called ``float``, as after the
        flight (a fixed position promises 10 cm at 3 sigma)."""
        self._p = p = _rtklib()
        opts, _ = resolve_options(get_engine("demo5"), base_ecef_m, None,
                                  {**LIVE_OPTIONS, **(overrides or {})})
        with tempfile.TemporaryDirectory(prefix="gs-rtk-") as tmp:
            conf = Path(tmp) / "live.conf"
            conf.write_text(conf_text(opts, ["groundstation: live demo5 options"]))
            p.resetsysopts()
            if not p.loadopts(str(conf), p.sysopts.ptr):
                raise EngineUnavailable("the engine did not accept its own options")
            self._popt, sopt, fopt = p.prcopt_t(), p.solopt_t(), p.filopt_t()
            p.getsysopts(self._popt, sopt, fopt)
        self._popt.mode = p.PMODE_KINEMA
        self.rtk = p.rtk_t()
        p.rtkinit(self.rtk, self._popt)
        self.nav = p.nav_t()
        self._eph_slots = p.Arr1Deph_t(2 * p.MAXSAT)
        self.nav.eph = self._eph_slots
        self.nav.n = self.nav.nmax = 2 * p.MAXSAT
        self._known: set[int] = set()
        self._asm: lnav.EphemerisAssembler | None = None
        self._base: deque[RawEpoch] = deque(maxlen=BASE_BUFFER)
        self.base_ecef_m = base_ecef_m
        self.base_how = "given"
        """How the base coordinates were given (``given with --base-llh ...``), for the check."""
        self._base_fixes: list[tuple[float, float, float]] = []
        self._base_fix_ns: int | None = None
        self._iono: tuple[tuple[float, float, float, float],
                          tuple[float, float, float, float]] | None = None
        self.base_check = ""
        """The given coordinates against the base's own fixes, once made (:meth:`_check_base`)."""
        self.base_check_alert = False
        """The check found them doubtful or far off (``solve`` would warn or refuse)."""
        self.base_name = ""
        """`` station NAME`` for the messages, when the base is a station on the bus."""
        self._obs = p.Arr1Dobsd_t(2 * p.MAXOBS)
        self.solved = 0
        self.restarts = 0
        self.restart = restart
        self._recent: deque[RawEpoch] = deque(maxlen=GAP_CONTEXT)
        """The last rover epochs received, the context of the gap check."""
        self._ephemerides: dict[int, BroadcastEphemeris] = {}
        self.gaps_checked = 0
        self.gap_slips = 0
        self._previous: frozenset[int] = frozenset()
        """The GPS satellites with a carrier phase in the previous rover epoch (an epoch of the
        outage itself, with none, counts: a satellite absent from it did not keep lock)."""

    # -- inputs --------------------------------------------------------------------------------

    def add_subframe(self, sf: Subframe, week_hint: int) -> bool:
        """A GPS subframe from either receiver; True when it completed a new ephemeris."""
        if sf.gnss != GNSS_GPS:
            return False
        words = sf.data_words()
        try:
            iono = lnav.decode_iono_utc(words) if lnav.subframe_id(words) == 4 else None
        except lnav.LnavError:  # not a subframe (its own checks follow in the assembler)
            iono = None
        if iono is not None:
            self._iono = (iono.alpha, iono.beta)
        if self._asm is None:
            self._asm = lnav.EphemerisAssembler(week_hint)
        eph = self._asm.add(sf.sv, sf.data_words())
        if eph is None:
            return False
        self._set_eph(eph)
        return True

    def add_ephemeris(self, eph: BroadcastEphemeris) -> None:
        """An ephemeris known otherwise (AID-EPH, a navigation file)."""
        self._set_eph(eph)

    def add_base(self, epoch: RawEpoch) -> None:
        """A base epoch (kept a while: the rover's, delayed by its radio, may come later)."""
        if self._base and epoch.t_gps_ns <= self._base[-1].t_gps_ns:
            self._base.clear()  # the base restarted, or its clock stepped back
        self._base.append(epoch)
        if not self.base_check:
            self._check_base(epoch)

    def _check_base(self, epoch: RawEpoch) -> None:
        """A single-point fix of the base from ``epoch`` (one a second); with
        :data:`BASE_CHECK_FIXES` of them, the given base coordinates checked against their mean
        as ``solve`` checks them against the base receiver's own fixes (``base_check``,
        ``base_check_alert``)."""
        from groundstation.errors import ConfigError
        from groundstation.solve.base import compare_base

        last = self._base_fix_ns
        if last is not None and epoch.t_gps_ns - last < BASE_CHECK_SPACING_S * 1e9:
            return
        gps = [s for s in epoch.sats if s.gnss == GNSS_GPS and s.pseudorange_m > 0
               and s.sv in self._ephemerides]
        if len(gps) < 5:
            return
        x = self._single_point(epoch.t_gps_ns, epoch.tow_ns, gps)
        if x is None:
            return
        self._base_fix_ns = epoch.t_gps_ns
        self._base_fixes.append((float(x[0]), float(x[1]), float(x[2])))
        if len(self._base_fixes) < BASE_CHECK_FIXES:
            return
        try:
            text, doubtful = compare_base(
                self._base_fixes, self.base_ecef_m, self.base_how,
                "{n} single-point fixes from the base's own pseudoranges")
        except ConfigError as err:  # solve would refuse them: live, the operator is told
            text, doubtful = f"{err.key}: {err.message}", True
        self.base_check, self.base_check_alert = text, doubtful

    def _single_point(self, t_gps_ns: int, tow_ns: int, sats: list[SatObs],
                      ) -> tuple[float, float, float] | None:
        """A receiver's single-point position from its GPS pseudoranges, corrected for the
        troposphere (Saastamoinen) and the ionosphere (the broadcast Klobuchar model, from
        subframe 4 page 18 once received; RTKLIB's default coefficients before): the
        ionosphere alone moves an uncorrected fix by tens of metres."""
        from groundstation.geodesy import azimuth_elevation, ecef_to_llh
        from groundstation.gnss.atmosphere import klobuchar_delay_m, saastamoinen_delay_m
        from groundstation.gnss.geometry import SatGeometry

        t = np.array([t_gps_ns], dtype=np.int64)
        svs = [s.sv for s in sats]
        ephs = [self._ephemerides[s.sv] for s in sats]
        pr = np.array([[s.pseudorange_m for s in sats]])
        geo = SatGeometry(t, svs, pr, ephs, self.base_ecef_m)
        x = geo.position(0)
        # the satellites' positions from the first geometry: the delays move their
        # transmission times by tens of nanoseconds, the positions by a fraction of a mm
        sat_pos = [(float(p[0]), float(p[1]), float(p[2])) for p in geo.pos[0]]
        seen = np.all(np.isfinite(geo.pos[0]), axis=1).tolist()
        for _ in range(2):  # the delays from where the fix is, then the fix again
            if x is None:
                return None
            here = (float(x[0]), float(x[1]), float(x[2]))
            lat, lon, h = ecef_to_llh(*here)
            azel = np.array([azimuth_elevation(p, here) if ok else (0.0, -90.0)
                             for p, ok in zip(sat_pos, seen, strict=True)])
            az, el = azel[:, 0], azel[:, 1]
            keep = el >= 5.0
            if int(keep.sum()) < 5:
                return None
            alpha, beta = self._iono or KLOBUCHAR_DEFAULT
            delay = (saastamoinen_delay_m(lat, np.full(el.shape, h), np.maximum(el, 5.0))
                     + klobuchar_delay_m(alpha, beta, lat, lon, az, np.maximum(el, 5.0),
                                         (tow_ns / 1e9) % 86400.0))
            x = SatGeometry(t, [sv for sv, k in zip(svs, keep, strict=True) if k],
                            (pr - delay)[:, keep], [e for e, k in zip(ephs, keep, strict=True)
                                                    if k], here).position(0)
        return None if x is None else (float(x[0]), float(x[1]), float(x[2]))

    def _base_for(self, t_gps_ns: int) -> RawEpoch | None:
        """The latest base epoch not after ``t_gps_ns``."""
        for b in reversed(self._base):
            if b.t_gps_ns <= t_gps_ns:
                return b
        return None

    def add_rover(self, epoch: RawEpoch) -> LiveSolution:
        """Solve one rover epoch with the latest base epoch not after it."""
        t = epoch.t_gps_ns
        base = self._base_for(t)
        age = None if base is None else (t - base.t_gps_ns) / 1e9
        why = (f"no epoch from the base{self.base_name} yet" if not self._base else
               "the base's epochs are all later than this one" if base is None else
               f"the base's latest epoch is {age:.0f} s old" if age is not None
               and age > MAX_BASE_AGE_S else
               f"ephemerides of {len(self._known)} satellites, 4 needed"
               if len(self._known) < MIN_EPHEMERIDES else "")
        if why or base is None:
            return LiveSolution(t, "none", 0.0, 0, age, None, None, why)
        epoch = self._flag_gap_slips(epoch)
        why = self._restart_if_unconnected(epoch)
        n = self._fill(epoch, 1, 0)
        n = self._fill(base, 2, n)
        p = self._p
        p.rtkpos(self.rtk, self._obs[0], n, self.nav)
        self.solved += 1
        sol = self.rtk.sol
        stat = int(sol.stat)
        if stat == 0:
            return LiveSolution(t, "none", 0.0, int(sol.ns), age, None, None,
                                "no solution: too few satellites in common with the base, or "
                                "the base position is wrong (kilometres off?)")
        xyz = (float(sol.rr[0]), float(sol.rr[1]), float(sol.rr[2]))
        sd = _sd_enu(xyz, [float(sol.qr[i]) for i in range(6)])
        quality = QUALITY.get(stat, "single")
        if quality == "fix" and sd is not None and max(sd) > self.fixed_max_sigma_m:
            quality, why = "float", (
                f"integer solution with a sigma of {max(sd) * 100:.1f} cm: not called fixed "
                f"(over {self.fixed_max_sigma_m * 100:.1f} cm, the post-flight rule)")
        return LiveSolution(t, quality, float(sol.ratio), int(sol.ns), age, xyz, sd, why)

    def _flag_gap_slips(self, epoch: RawEpoch) -> RawEpoch:
        """The epoch with LLI bit 0 set on every satellite whose phase the post-flight
        conditioning (:func:`groundstation.solve.conditioning.condition`, on the last
        :data:`GAP_CONTEXT` epochs and this one) does not find continuous across a radio gap
        before it.

        RXM-RAW has no lock time: a slip's LLI travels in the epoch after it, and when the radio
        drops that epoch the slip is invisible; the filter would carry the ambiguity across it
        (measured: docs/live-rtk.md). A jump the conditioning would repair is flagged too: the
        live filter starts that ambiguity again rather than taking a phase correction it cannot
        see confirmed by later epochs."""
        from groundstation.solve import conditioning

        recent = list(self._recent)
        self._recent.append(epoch)
        if len(recent) < 3 or self.solved == 0:
            return epoch
        times = np.array([e.t_gps_ns for e in recent], dtype=np.int64)
        step = conditioning.STEP_INTERVALS * float(np.median(np.diff(times)))
        rr = self.rtk.sol.rr
        if epoch.t_gps_ns - int(times[-1]) <= step or not any(float(rr[i]) for i in range(3)):
            return epoch
        obs = _window_obs([*recent, epoch])
        out, _ = conditioning.condition(obs, list(self._ephemerides.values()),
                                        (float(rr[0]), float(rr[1]), float(rr[2])))
        self.gaps_checked += 1
        correction = out.cp_cyc - obs.cp_cyc
        last = len(recent)
        before = {int(obs.prn[k]): float(correction[k]) for k in np.flatnonzero(obs.epoch < last)}
        slips = {int(obs.prn[k]) for k in np.flatnonzero(obs.epoch == last)
                 if out.lli[k] & LLI_SLIP
                 or abs(float(correction[k]) - before.get(int(obs.prn[k]), 0.0)) > 1e-9}
        if not slips:
            return epoch
        self.gap_slips += len(slips)
        sats = tuple(dataclasses.replace(s, lli=s.lli | LLI_SLIP)
                     if s.gnss == GNSS_GPS and s.sv in slips else s for s in epoch.sats)
        marked = dataclasses.replace(epoch, sats=sats)
        self._recent[-1] = marked
        return marked

    def _restart_if_unconnected(self, epoch: RawEpoch) -> str:
        """Restart the filter from the single-point position when fewer than
        :data:`MIN_KEPT_LOCK` satellites kept lock since the previous epoch (a bridge, a
        canopy, the whole sky lost): no carrier phase then connects the filter's state to this
        epoch. Its ambiguities are all void, and the position and velocity it carried across
        the outage rest on the dynamic model alone (process noise of a fraction of a m/s²,
        where a multicopter accelerates by metres per s²): kept, they bias the new float
        solution by metres under a sigma of decimetres, and fix-and-hold then holds a wrong
        fix (measured: docs/live-rtk.md). Returns the reason said with the epoch, or ``""``."""
        now = frozenset(s.sv for s in epoch.sats
                        if s.gnss == GNSS_GPS and s.cp_valid and _finite(s))
        kept = {s.sv for s in epoch.sats if s.sv in self._previous and s.gnss == GNSS_GPS
                and s.cp_valid and _finite(s) and not s.lli & 1}
        self._previous = now
        if not self.restart or self.solved == 0 or len(now) < MIN_KEPT_LOCK or len(
                kept) >= MIN_KEPT_LOCK:
            return ""
        p = self._p
        p.rtkfree(self.rtk)
        self.rtk = p.rtk_t()
        p.rtkinit(self.rtk, self._popt)
        self.restarts += 1
        return (f"filter restarted: {len(kept)} satellites kept lock since the last epoch "
                f"({MIN_KEPT_LOCK} needed to carry its state)")

    # -- RTKLIB's structures -------------------------------------------------------------------

    def _fill(self, epoch: RawEpoch, rcv: int, start: int) -> int:
        p = self._p
        week, tow_ns = divmod(epoch.t_gps_ns, gpstime.NS_PER_WEEK)
        when = p.gpst2time(int(week), tow_ns / 1e9)
        k = start
        for s in epoch.sats:
            if s.gnss != GNSS_GPS or not s.pr_valid or k >= 2 * p.MAXOBS:
                continue
            o = self._obs[k]
            o.time = when
            o.sat = p.satno(p.SYS_GPS, s.sv)
            o.rcv = rcv
            o.code[0] = p.CODE_L1C
            o.P[0] = s.pseudorange_m
            o.L[0] = s.carrier_phase_cyc if s.cp_valid and _finite(s) else 0.0
            o.D[0] = s.doppler_hz
            o.SNR[0] = int(round(s.cno_dbhz / SNR_UNIT))
            o.LLI[0] = s.lli & 3
            k += 1
        return k

    def _set_eph(self, eph: BroadcastEphemeris) -> None:
        self._ephemerides[eph.sv] = eph
        p = self._p
        sat = p.satno(p.SYS_GPS, eph.sv)
        e = self._eph_slots[sat - 1]
        e.sat = sat
        e.iode, e.iodc, e.sva, e.svh = eph.iode, eph.iodc, eph.ura_index, eph.health
        e.week, e.code, e.flag = eph.week, eph.code_on_l2, eph.l2p_data_flag
        e.toe = p.gpst2time(eph.week, eph.toe_s)
        e.toc = p.gpst2time(eph.week, eph.toc_s)
        e.ttr = p.gpst2time(eph.week, eph.tow_s if eph.tow_s is not None else eph.toe_s)
        e.A = eph.sqrt_a_sqrt_m ** 2
        e.e, e.i0, e.OMG0 = eph.e, eph.i0_rad, eph.omega0_rad
        e.omg, e.M0, e.deln = eph.omega_rad, eph.m0_rad, eph.delta_n_rad_s
        e.OMGd, e.idot = eph.omega_dot_rad_s, eph.idot_rad_s
        e.crc, e.crs, e.cuc, e.cus = eph.crc_m, eph.crs_m, eph.cuc_rad, eph.cus_rad
        e.cic, e.cis = eph.cic_rad, eph.cis_rad
        e.toes = eph.toe_s
        e.fit = 4.0 if eph.fit_interval_flag == 0 else 6.0
        e.f0, e.f1, e.f2 = eph.af0_s, eph.af1_s_s, eph.af2_s_s2
        e.tgd[0] = eph.tgd_s
        self._known.add(eph.sv)


def _finite(s: SatObs) -> bool:
    return math.isfinite(s.carrier_phase_cyc) and s.carrier_phase_cyc != 0.0


def _sd_enu(xyz: tuple[float, float, float], q: list[float],
            ) -> tuple[float, float, float] | None:
    """East/north/up sigmas from RTKLIB's ECEF covariance (xx, yy, zz, xy, yz, zx)."""
    from groundstation.geodesy import ecef_to_llh, enu_rotation

    if not any(q):
        return None
    c = np.array([[q[0], q[3], q[5]], [q[3], q[1], q[4]], [q[5], q[4], q[2]]])
    lat, lon, _ = ecef_to_llh(*xyz)
    r = np.array(enu_rotation(lat, lon))
    d = np.diag(r @ c @ r.T)
    e, n, u = (float(math.sqrt(max(v, 0.0))) for v in d)
    return e, n, u


def _window_obs(epochs: list[RawEpoch]) -> ObsSet:
    """A few rover epochs as the conditioning's observations (GPS phases of RXM-RAW)."""
    from groundstation.offline.rinex.observations import ObsSet

    rows = [(i, s) for i, e in enumerate(epochs) for s in e.sats
            if s.gnss == GNSS_GPS and s.cp_valid and s.pr_valid and _finite(s)]
    n = len(rows)
    return ObsSet(
        t_gps_ns=np.array([e.t_gps_ns for e in epochs], dtype=np.int64),
        leap_s=np.full(len(epochs), -1, dtype=np.int64),
        epoch=np.array([i for i, _ in rows], dtype=np.int64),
        sys=np.full(n, "G", dtype="<U2"), prn=np.array([s.sv for _, s in rows], dtype=np.int64),
        code=np.full(n, "1C", dtype="<U2"),
        pr_m=np.array([s.pseudorange_m for _, s in rows], dtype=np.float64),
        cp_cyc=np.array([s.carrier_phase_cyc for _, s in rows], dtype=np.float64),
        do_hz=np.array([s.doppler_hz for _, s in rows], dtype=np.float64),
        cno_dbhz=np.array([s.cno_dbhz for _, s in rows], dtype=np.float64),
        lli=np.array([s.lli for _, s in rows], dtype=np.int64), glo_fcn={}, source="RXM-RAW")


# -- recorded streams ---------------------------------------------------------------------------


def measurements(data: bytes) -> list[RawEpoch | Subframe]:
    """A receiver's stream decoded as its daemon decodes it: the epochs and subframes, in
    stream order (the base's stream for :class:`LiveRtkSink`, recordings replayed live)."""
    return [r for r in _decoded(data) if isinstance(r, (RawEpoch, Subframe))]


def mark_times(data: bytes) -> list[int]:
    """The exposures' times (GPS ns, falling edge) of the time marks in a rover's stream, as
    :class:`FixWatch` takes them."""
    return [r.falling_t_gps_ns for r in _decoded(data)
            if isinstance(r, TimeMark) and r.falling_t_gps_ns]


def _decoded(data: bytes) -> list[Any]:
    from groundstation.ubx.decode import Decoder
    from groundstation.ubx.framer import UbxFramer

    framer, decoder = UbxFramer(), Decoder()
    return [decoder.decode(frame) for frame in framer.feed(data, 0) + framer.flush(0)]


class BaseFeed:
    """A base's decoded stream handed to the engine as the rover's epochs reach its times (the
    base's stream arrives first, as from a base on the laptop's serial port)."""

    def __init__(self, engine: LiveRtk, items: list[RawEpoch | Subframe]) -> None:
        self.engine, self.items, self._k = engine, items, 0

    def until(self, t_gps_ns: int, week: int) -> None:
        """Every base item up to the first base epoch after ``t_gps_ns``."""
        while self._k < len(self.items):
            b = self.items[self._k]
            if isinstance(b, RawEpoch):
                if b.t_gps_ns > t_gps_ns:
                    return
                self.engine.add_base(b)
            else:
                self.engine.add_subframe(b, week)
            self._k += 1


def solve_recorded(rover: bytes, base: bytes, base_ecef_m: tuple[float, float, float],
                   *, restart: bool = True, overrides: dict[str, str] | None = None,
                   ) -> list[LiveSolution]:
    """Two recorded streams solved epoch by epoch as the live engine would have solved them
    (``overrides``: engine options over the live engine's, to measure what they change)."""
    engine = LiveRtk(base_ecef_m, overrides, restart=restart)
    base_items = measurements(base)
    feed = BaseFeed(engine, base_items)
    week = next((b.gps_week for b in base_items if isinstance(b, RawEpoch)), 0)
    out = []
    for r in measurements(rover):
        if isinstance(r, Subframe):
            engine.add_subframe(r, week)
            continue
        feed.until(r.t_gps_ns, r.gps_week)
        out.append(engine.add_rover(r))
    return out


# -- the operator's alert -----------------------------------------------------------------------

FIX_LOST_ALERT_S = 10.0
"""No fixed live position for this long while marks come in: the operator is told (a photo
taken then may have no fixed position after the flight either; at 5 Hz, 50 epochs)."""
MARKS_RECENT_S = 10.0
"""Marks "come in" when one arrived within this long."""


class FixWatch:
    """When to tell the operator that the live fix is lost while photos are being taken: after
    :data:`FIX_LOST_ALERT_S` without a fix and with a mark in the last :data:`MARKS_RECENT_S`;
    and when the fix is back. Times are the rover's epochs (GPS ns)."""

    def __init__(self) -> None:
        self.last_fix_ns: int | None = None
        self.last_mark_ns: int | None = None
        self.raised_since_ns: int | None = None
        self.marks_since = 0

    def mark(self, t_gps_ns: int) -> None:
        self.last_mark_ns = t_gps_ns
        if self.raised_since_ns is not None:
            self.marks_since += 1

    def update(self, sol: LiveSolution) -> tuple[str, dict[str, Any]] | None:
        """``(event kind, data)`` to raise or clear, or None."""
        from groundstation import events

        t = sol.t_gps_ns
        if sol.quality == "fix":
            self.last_fix_ns = t
            if self.raised_since_ns is not None:
                lost = (t - self.raised_since_ns) / 1e9
                self.raised_since_ns = None
                return events.RTK_FIX_REGAINED, {"lost_s": round(lost, 1)}
            return None
        since = self.last_fix_ns
        if self.raised_since_ns is not None or since is None or self.last_mark_ns is None:
            return None
        if (t - since) / 1e9 >= FIX_LOST_ALERT_S and (
                t - self.last_mark_ns) / 1e9 <= MARKS_RECENT_S:
            self.raised_since_ns, self.marks_since = since, 0
            return events.RTK_FIX_LOST, {"since_t_gps_ns": since,
                                         "lost_s": round((t - since) / 1e9, 1)}
        return None


def watch_recorded(solutions: list[LiveSolution], marks: list[int],
                   ) -> list[tuple[int, str, dict[str, Any]]]:
    """The operator's alerts over solved epochs and the flight's mark times
    (:func:`mark_times`), as the live :class:`FixWatch` raises and clears them:
    ``(rover epoch, event kind, data)``."""
    watch, out, k = FixWatch(), [], 0
    for s in solutions:
        while k < len(marks) and marks[k] <= s.t_gps_ns:
            watch.mark(marks[k])
            k += 1
        said = watch.update(s)
        if said is not None:
            out.append((s.t_gps_ns, *said))
    return out


class LiveRtkSink:
    """A daemon's pipeline sink (the demo's): its rover epochs solved against a base stream
    known in advance (the simulator's, each base item handed over once the rover's epochs
    reach its time: the base's stream arrives first, as over a base on the laptop's serial
    port); each solution published into the pipeline (the publisher puts it on ``.../rtk``),
    the operator's alert as events."""

    name = "rtk"
    accepts = frozenset((RawEpoch, Subframe, TimeMark))

    def __init__(self, base_ecef_m: tuple[float, float, float],
                 base_items: list[RawEpoch | Subframe], clock: Any = None) -> None:
        import time

        self.engine = LiveRtk(base_ecef_m)
        self._base = BaseFeed(self.engine, base_items)
        self.watch = FixWatch()
        self.solutions: list[LiveSolution] = []
        self._clock = clock or time.time_ns

    def handle(self, item: Any, publish: Any) -> None:
        from groundstation.records import Event

        if isinstance(item, TimeMark):
            if item.falling_t_gps_ns is not None:
                self.watch.mark(item.falling_t_gps_ns)
            return
        if isinstance(item, Subframe):
            self.engine.add_subframe(item, gpstime.week_tow(gpstime.unix_to_gps_ns(
                self._clock()))[0])
            return
        if not isinstance(item, RawEpoch):
            return
        self._base.until(item.t_gps_ns, item.gps_week)
        sol = dataclasses.replace(self.engine.add_rover(item), rx_host_ns=item.t_host_ns)
        self.solutions.append(sol)
        publish(sol)
        raised = self.watch.update(sol)
        if raised is not None:
            from groundstation import events

            kind, data = raised
            text = (f"live fix lost {data['lost_s']:g} s ago while photos are being taken: "
                    "they may get no fixed position (keep the drone in open sky, check the "
                    "base)" if kind == events.RTK_FIX_LOST else
                    f"live fix back after {data['lost_s']:g} s")
            publish(Event(kind, self._clock(), text, events.CATALOGUE[kind].severity, data))

    async def consume(self, inbox: Any, publish: Any) -> None:
        from groundstation.live.fanout import InboxClosed

        while True:
            try:
                item = await inbox.get()
            except InboxClosed:
                return
            self.handle(item, publish)


# -- the ``rtk`` service: the bus in, the bus out ----------------------------------------------


@dataclass
class RtkRun:
    """What a live run did (for its printout and the tests)."""

    rover_epochs: int = 0
    base_epochs: int = 0
    subframes: int = 0
    bad_messages: int = 0
    published: int = 0
    by_quality: dict[str, int] | None = None
    base_check: str = ""


def run_rtk(
    rover: str, base: str, base_ecef_m: tuple[float, float, float], settings: Any,
    *, duration_s: float = 0.0, print_every_s: float = 1.0,
    out: Any = None, stop: Any = None, base_how: str = "given",
) -> RtkRun:
    """Subscribe to both stations' ``obs``, solve every rover epoch, publish
    ``groundstation/<rover>/rtk`` (JSON, :meth:`LiveSolution.message`) and print a line a
    second; until Ctrl-C, ``duration_s`` or ``stop()``. Once the base has sent
    :data:`BASE_CHECK_FIXES` epochs, the given base coordinates (``base_how``: how they were
    given) are checked against its own single-point fixes and the result printed, as an
    ``ALERT`` line where ``solve`` would warn or refuse.

    Raises:
        EngineUnavailable: pyrtklib5 is missing.
        GroundstationError: the bus cannot be opened.
    """
    import queue
    import sys
    import time

    from groundstation import events
    from groundstation.bus import decode, encode, key, open_bus
    from groundstation.live import obswire

    engine = LiveRtk(base_ecef_m)
    engine.base_name = f" station {base!r}"
    engine.base_how = base_how
    inbox: queue.Queue[tuple[str, bytes]] = queue.Queue(maxsize=10_000)
    run = RtkRun(by_quality={})
    bus = open_bus(settings)
    out = out or sys.stdout

    def on(which: str) -> Any:
        def handler(_key: str, payload: bytes) -> None:
            try:
                inbox.put_nowait((which, payload))
            except queue.Full:
                run.bad_messages += 1
        return handler

    bus.subscribe(key(rover, "obs"), on("rover"))
    bus.subscribe(key(rover, "timemark"), on("mark"))
    watch = FixWatch()
    bus.subscribe(key(base, "obs"), on("base"))
    publish = bus.publisher(key(rover, "rtk"))
    t_end = time.monotonic() + duration_s if duration_s > 0 else None
    next_print = 0.0
    week_hint = gpstime.week_tow(gpstime.unix_to_gps_ns(time.time_ns()))[0]
    try:
        while not (stop and stop()) and (t_end is None or time.monotonic() < t_end):
            try:
                which, payload = inbox.get(timeout=0.2)
            except queue.Empty:
                continue
            if which == "mark":
                try:
                    t_mark = decode(payload).get("falling_t_gps_ns")
                except ValueError:
                    run.bad_messages += 1
                    continue
                if isinstance(t_mark, int):
                    watch.mark(t_mark)
                continue
            try:
                rec = obswire.decode(payload)
            except obswire.ObsWireError:
                run.bad_messages += 1
                continue
            if isinstance(rec, Subframe):
                run.subframes += 1
                engine.add_subframe(rec, week_hint)
                continue
            week_hint = rec.gps_week
            if which == "base":
                run.base_epochs += 1
                engine.add_base(rec)
                if engine.base_check and not run.base_check:
                    run.base_check = engine.base_check
                    out.write(("ALERT base coordinates: " if engine.base_check_alert else
                               "rtk: base check: ") + engine.base_check.rstrip(".")
                              + (". Every live position carries the base's error: check the "
                                 "coordinates (solve checks them the same way)."
                                 if engine.base_check_alert else "") + "\n")
                    out.flush()
                continue
            run.rover_epochs += 1
            sol = engine.add_rover(rec)
            raised = watch.update(sol)
            body = sol.message()
            if watch.raised_since_ns is not None:
                body["alert"] = "fix_lost"
            publish(encode("rtk", body, station=rover))
            if raised is not None:
                out.write(("ALERT live fix lost while photos are being taken"
                           if raised[0] == events.RTK_FIX_LOST else "live fix back")
                          + f" ({raised[1]['lost_s']:g} s)\n")
            run.published += 1
            assert run.by_quality is not None
            run.by_quality[sol.quality] = run.by_quality.get(sol.quality, 0) + 1
            now = time.monotonic()
            if now >= next_print:
                next_print = now + print_every_s
                out.write(_line(sol, engine.base_check_alert) + "\n")
                out.flush()
    finally:
        bus.close()
    return run


def _line(s: LiveSolution, base_doubtful: bool = False) -> str:
    """One printed line: time, quality, ratio, satellites, base age, position and sigma; after
    the base check found the base coordinates doubtful, every line says so (a surveyor who
    missed the one ALERT line would otherwise take the centimetre sigmas at their word)."""
    line = _line_of(s)
    return f"{line}  [base coordinates doubtful: see the ALERT]" if base_doubtful else line


def _line_of(s: LiveSolution) -> str:
    when = gpstime.gps_as_datetime(s.t_gps_ns).strftime("%H:%M:%S.%f")[:-5]
    age = "-" if s.age_s is None else f"{s.age_s:.1f} s"
    # fix-and-hold's 999.9 is "held" (its ambiguities held); 0: no resolution tried
    ratio = "held" if s.ratio >= 999 else "-" if s.ratio <= 0 else f"{s.ratio:.1f}"
    head = f"{when} GPS  {s.quality:<6} ratio {ratio:>5}  sats {s.sats:2d}  base age {age}"
    if s.ecef_m is None:
        return f"{head}  ({s.why})" if s.why else head
    from groundstation.geodesy import ecef_to_llh

    lat, lon, h = ecef_to_llh(*s.ecef_m)
    sd = "" if s.sd_enu_m is None else (
        "  σ e/n/u " + "/".join(f"{v * 100:.1f}" for v in s.sd_enu_m) + " cm")
    return f"{head}  {lat:.8f} {lon:.8f} {h:.3f} m{sd}"
