"""RTKLIB 2.4.3 b34 ``sysopts[]`` (src/options.c): the option table of Debian's ``rnx2rtkp``.

Transcribed from tomojitakasu/RTKLIB branch rtklib_2.4.3 (BSD-2-Clause), because the binary does
not expose its table; ``tests/unit/test_engine_options.py`` checks these names against the strings
of the installed binary. Rows are (name, format, comment): format 0 int, 1 float, 2 string,
3 enumeration whose comment lists ``value:name`` pairs.
"""

from __future__ import annotations

SWTOPT = "0:off,1:on"
MODOPT = (
    "0:single,1:dgps,2:kinematic,3:static,"
    "4:movingbase,5:fixed,6:ppp-kine,7:ppp-static,8:ppp-fixed"
)
FRQOPT = "1:l1,2:l1+2,3:l1+2+3,4:l1+2+3+4,5:l1+2+3+4+5"
TYPOPT = "0:forward,1:backward,2:combined"
IONOPT = "0:off,1:brdc,2:sbas,3:dual-freq,4:est-stec,5:ionex-tec,6:qzs-brdc"
TRPOPT = "0:off,1:saas,2:sbas,3:est-ztd,4:est-ztdgrad"
EPHOPT = "0:brdc,1:precise,2:brdc+sbas,3:brdc+ssrapc,4:brdc+ssrcom"
NAVOPT = "1:gps+2:sbas+4:glo+8:gal+16:qzs+32:bds+64:navic"
GAROPT = "0:off,1:on"
SOLOPT = "0:llh,1:xyz,2:enu,3:nmea"
TSYOPT = "0:gpst,1:utc,2:jst"
TFTOPT = "0:tow,1:hms"
DFTOPT = "0:deg,1:dms"
HGTOPT = "0:ellipsoidal,1:geodetic"
GEOOPT = "0:internal,1:egm96,2:egm08_2.5,3:egm08_1,4:gsi2000"
STAOPT = "0:all,1:single"
STSOPT = "0:off,1:state,2:residual"
ARMOPT = "0:off,1:continuous,2:instantaneous,3:fix-and-hold"
POSOPT = "0:llh,1:xyz,2:single,3:posfile,4:rinexhead,5:rtcm,6:raw"
TIDEOPT = "0:off,1:on,2:otl"
PHWOPT = "0:off,1:on,2:precise"

SYSOPTS_B34: tuple[tuple[str, int, str], ...] = (
    ("pos1-posmode", 3, MODOPT),
    ("pos1-frequency", 3, FRQOPT),
    ("pos1-soltype", 3, TYPOPT),
    ("pos1-elmask", 1, "deg"),
    ("pos1-snrmask_r", 3, SWTOPT),
    ("pos1-snrmask_b", 3, SWTOPT),
    ("pos1-snrmask_L1", 2, ""),
    ("pos1-snrmask_L2", 2, ""),
    ("pos1-snrmask_L5", 2, ""),
    ("pos1-dynamics", 3, SWTOPT),
    ("pos1-tidecorr", 3, TIDEOPT),
    ("pos1-ionoopt", 3, IONOPT),
    ("pos1-tropopt", 3, TRPOPT),
    ("pos1-sateph", 3, EPHOPT),
    ("pos1-posopt1", 3, SWTOPT),
    ("pos1-posopt2", 3, SWTOPT),
    ("pos1-posopt3", 3, PHWOPT),
    ("pos1-posopt4", 3, SWTOPT),
    ("pos1-posopt5", 3, SWTOPT),
    ("pos1-posopt6", 3, SWTOPT),
    ("pos1-exclsats", 2, "prn ..."),
    ("pos1-navsys", 0, NAVOPT),
    ("pos2-armode", 3, ARMOPT),
    ("pos2-gloarmode", 3, GAROPT),
    ("pos2-bdsarmode", 3, SWTOPT),
    ("pos2-arthres", 1, ""),
    ("pos2-arthres1", 1, ""),
    ("pos2-arthres2", 1, ""),
    ("pos2-arthres3", 1, ""),
    ("pos2-arthres4", 1, ""),
    ("pos2-arlockcnt", 0, ""),
    ("pos2-arelmask", 1, "deg"),
    ("pos2-arminfix", 0, ""),
    ("pos2-armaxiter", 0, ""),
    ("pos2-elmaskhold", 1, "deg"),
    ("pos2-aroutcnt", 0, ""),
    ("pos2-maxage", 1, "s"),
    ("pos2-syncsol", 3, SWTOPT),
    ("pos2-slipthres", 1, "m"),
    ("pos2-rejionno", 1, "m"),
    ("pos2-rejgdop", 1, ""),
    ("pos2-niter", 0, ""),
    ("pos2-baselen", 1, "m"),
    ("pos2-basesig", 1, "m"),
    ("out-solformat", 3, SOLOPT),
    ("out-outhead", 3, SWTOPT),
    ("out-outopt", 3, SWTOPT),
    ("out-outvel", 3, SWTOPT),
    ("out-timesys", 3, TSYOPT),
    ("out-timeform", 3, TFTOPT),
    ("out-timendec", 0, ""),
    ("out-degform", 3, DFTOPT),
    ("out-fieldsep", 2, ""),
    ("out-outsingle", 3, SWTOPT),
    ("out-maxsolstd", 1, "m"),
    ("out-height", 3, HGTOPT),
    ("out-geoid", 3, GEOOPT),
    ("out-solstatic", 3, STAOPT),
    ("out-nmeaintv1", 1, "s"),
    ("out-nmeaintv2", 1, "s"),
    ("out-outstat", 3, STSOPT),
    ("stats-eratio1", 1, ""),
    ("stats-eratio2", 1, ""),
    ("stats-errphase", 1, "m"),
    ("stats-errphaseel", 1, "m"),
    ("stats-errphasebl", 1, "m/10km"),
    ("stats-errdoppler", 1, "Hz"),
    ("stats-stdbias", 1, "m"),
    ("stats-stdiono", 1, "m"),
    ("stats-stdtrop", 1, "m"),
    ("stats-prnaccelh", 1, "m/s^2"),
    ("stats-prnaccelv", 1, "m/s^2"),
    ("stats-prnbias", 1, "m"),
    ("stats-prniono", 1, "m"),
    ("stats-prntrop", 1, "m"),
    ("stats-prnpos", 1, "m"),
    ("stats-clkstab", 1, "s/s"),
    ("ant1-postype", 3, POSOPT),
    ("ant1-pos1", 1, "deg|m"),
    ("ant1-pos2", 1, "deg|m"),
    ("ant1-pos3", 1, "m|m"),
    ("ant1-anttype", 2, ""),
    ("ant1-antdele", 1, "m"),
    ("ant1-antdeln", 1, "m"),
    ("ant1-antdelu", 1, "m"),
    ("ant2-postype", 3, POSOPT),
    ("ant2-pos1", 1, "deg|m"),
    ("ant2-pos2", 1, "deg|m"),
    ("ant2-pos3", 1, "m|m"),
    ("ant2-anttype", 2, ""),
    ("ant2-antdele", 1, "m"),
    ("ant2-antdeln", 1, "m"),
    ("ant2-antdelu", 1, "m"),
    ("ant2-maxaveep", 0, ""),
    ("ant2-initrst", 3, SWTOPT),
    ("misc-timeinterp", 3, SWTOPT),
    ("misc-sbasatsel", 0, "0:all"),
    ("misc-rnxopt1", 2, ""),
    ("misc-rnxopt2", 2, ""),
    ("misc-pppopt", 2, ""),
    ("file-satantfile", 2, ""),
    ("file-rcvantfile", 2, ""),
    ("file-staposfile", 2, ""),
    ("file-geoidfile", 2, ""),
    ("file-ionofile", 2, ""),
    ("file-dcbfile", 2, ""),
    ("file-eopfile", 2, ""),
    ("file-blqfile", 2, ""),
    ("file-tempdir", 2, ""),
    ("file-geexefile", 2, ""),
    ("file-solstatfile", 2, ""),
    ("file-tracefile", 2, ""),
)
