"""RTKLIB processing options: an engine's option table, validation, ``.conf`` files, our defaults.

An RTKLIB engine is configured by ``key=value`` lines that its ``loadopts`` matches against its
``sysopts[]`` table. RTKLIB itself is lenient: it skips unknown keys without a word (it matches
keys by substring) and reads numbers with ``atoi``/``atof``. Here every key and value is checked
against the engine's own table before the engine runs, so a typo exits 2 naming the key.
"""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from groundstation.errors import ConfigError

FMT_INT, FMT_FLOAT, FMT_STR, FMT_ENUM = 0, 1, 2, 3
_FORMAT_NAMES = {FMT_INT: "integer", FMT_FLOAT: "number", FMT_STR: "text", FMT_ENUM: "choice"}


@dataclass(frozen=True, slots=True)
class OptionSpec:
    """One row of an engine's ``sysopts[]``: name, format (0 int 1 float 2 str 3 enum), comment."""

    name: str
    format: int
    comment: str

    def choices(self) -> dict[str, int]:
        """Enumeration names -> values (``"0:off,1:on"``); empty for non-enumerations."""
        if self.format != FMT_ENUM:
            return {}
        out: dict[str, int] = {}
        for item in self.comment.split(","):
            num, sep, name = item.partition(":")
            if sep and num.strip().lstrip("-").isdigit():
                out[name.strip()] = int(num)
        return out

    def bits(self) -> int | None:
        """The allowed bit mask of a ``1:gps+2:sbas+...`` integer option, else None."""
        if self.format != FMT_INT or "+" not in self.comment:
            return None
        vals = re.findall(r"(\d+):", self.comment)
        return sum(int(v) for v in vals) if vals else None


@dataclass(frozen=True, slots=True)
class OptionTable:
    """An engine's option table, in the engine's order."""

    engine: str
    specs: tuple[OptionSpec, ...]

    def __contains__(self, key: object) -> bool:
        return any(s.name == key for s in self.specs)

    def get(self, key: str) -> OptionSpec | None:
        """The row named exactly ``key`` (RTKLIB's own lookup is a substring match)."""
        for s in self.specs:
            if s.name == key:
                return s
        return None

    def names(self) -> list[str]:
        return [s.name for s in self.specs]

    @classmethod
    def from_rows(cls, engine: str, rows: Iterable[tuple[str, int, str]]) -> OptionTable:
        return cls(engine, tuple(OptionSpec(n, int(f), c) for n, f, c in rows))


def check_option(table: OptionTable, key: str, value: str, where: str) -> str:
    """``value`` normalised (stripped) if ``key`` is in ``table`` and ``value`` fits its format.

    Args:
        table: the engine's option table.
        key: option name, e.g. ``pos2-arthres``.
        value: the text after ``=``.
        where: what names the setting in an error (``--rtk-opt``, ``FILE:LINE``).

    Raises:
        ConfigError: unknown key, or a value that is not of the option's format or not one of its
            choices. The message names the key and says what would be accepted.
    """
    spec = table.get(key)
    label = f"{where} {key}" if where else key
    if spec is None:
        close = difflib.get_close_matches(key, table.names(), n=3)
        hint = f"; did you mean {', '.join(close)}?" if close else ""
        raise ConfigError(label, f"not an option of {table.engine}{hint}")
    v = value.strip()
    if spec.format == FMT_INT:
        try:
            n = int(v)
        except ValueError as err:
            raise ConfigError(label, f"expected an integer, got {value!r}") from err
        mask = spec.bits()
        if mask is not None and (n < 0 or n & ~mask):
            raise ConfigError(label, f"{n} is not a sum of {spec.comment}")
        return str(n)
    if spec.format == FMT_FLOAT:
        try:
            x = float(v)
        except ValueError as err:
            raise ConfigError(label, f"expected a number, got {value!r}") from err
        if not math.isfinite(x):
            raise ConfigError(label, f"expected a finite number, got {value!r}")
        return v
    if spec.format == FMT_ENUM:
        choices = spec.choices()
        if v in choices or (v.lstrip("-").isdigit() and int(v) in choices.values()):
            return v
        raise ConfigError(label, f"{value!r} is not one of {spec.comment}")
    return v


def check_options(table: OptionTable, opts: Mapping[str, str], where: str) -> dict[str, str]:
    """Every ``key=value`` of ``opts`` checked by :func:`check_option`, in order."""
    return {k: check_option(table, k, v, where) for k, v in opts.items()}


def parse_conf(text: str, source: str) -> list[tuple[str, str, int]]:
    """``(key, value, line)`` of an RTKLIB ``.conf`` text (``key = value  # comment``).

    Raises:
        ConfigError: a non-empty, non-comment line without ``=``.
    """
    out: list[tuple[str, str, int]] = []
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        key, sep, value = line.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"{source}:{n}", f"expected key=value, got {raw.strip()!r}")
        out.append((key.strip(), value.strip(), n))
    return out


def read_conf(path: Path, table: OptionTable) -> dict[str, str]:
    """The options of an RTKLIB ``.conf`` file, each checked against ``table``.

    Raises:
        ConfigError: unreadable file (named ``--rtk-conf``), bad line, unknown key or bad value
            (named ``FILE:LINE key``).
    """
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as err:
        raise ConfigError("--rtk-conf", f"{path}: cannot read: {err.strerror or err}") from err
    return {
        key: check_option(table, key, value, f"{path.name}:{line}")
        for key, value, line in parse_conf(text, path.name)
    }


def parse_assignments(items: Iterable[str], option: str = "--rtk-opt") -> dict[str, str]:
    """``key=value`` command-line items as a dict (later items win).

    Raises:
        ConfigError: an item without ``=`` or with an empty key.
    """
    out: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(option, f"expected key=value, got {item!r}")
        out[key.strip()] = value.strip()
    return out


def conf_text(opts: Mapping[str, str], header: Iterable[str] = ()) -> str:
    """An RTKLIB ``.conf`` file: ``key =value`` lines (RTKLIB keeps a space after ``=``)."""
    lines = [f"# {h}" for h in header]
    lines += [f"{k:<18} ={v}" for k, v in opts.items()]
    return "\n".join(lines) + "\n"


def base_position_options(base_ecef_m: tuple[float, float, float]) -> dict[str, str]:
    """The base station's known ECEF position as ``ant2-*`` options."""
    x, y, z = base_ecef_m
    return {
        "ant2-postype": "xyz",
        "ant2-pos1": f"{x:.4f}",
        "ant2-pos2": f"{y:.4f}",
        "ant2-pos3": f"{z:.4f}",
    }


# What our solution reader and every later stage rely on; a user's value for these is replaced
# (and reported), because a .conf exported from RTKPOST usually asks for llh or NMEA output.
OUTPUT_OPTIONS: dict[str, str] = {
    "out-solformat": "xyz",
    "out-outhead": "on",
    "out-timesys": "gpst",
    "out-timeform": "hms",
    "out-timendec": "6",
}


# -- the u-blox L1 5 Hz default -------------------------------------------------------------------
#
# Starting point: rtklibexplorer's published demo5 settings for u-blox M8T/M8N at 5 Hz,
# data/config/demo5_m8t_5hz.conf in rtklibexplorer/RTKLIB (tag v2.5.0, the engine pyrtklib5
# binds). Every value below is that file's unless a comment says why it differs for the
# LEA-6T (GPS L1 only, RXM-RAW at 5 Hz, radio gaps, half cycles; DOMAIN.md).

UBLOX_L1_5HZ: dict[str, str] = {
    "pos1-posmode": "kinematic",
    "pos1-frequency": "l1",
    # LEA-6T flights start and end with 15 min static: forward and backward runs each get an
    # initialisation, and the combined solution keeps the better-resolved of the two (M8T: forward,
    # for real-time-like use). engine.solve makes it of a forward and a backward run, merged by
    # engine/combine.py with a stricter check of the epochs both runs fixed than demo5's.
    "pos1-soltype": "combined",
    "pos1-elmask": "15",
    "pos1-snrmask_r": "off",
    "pos1-snrmask_b": "off",
    "pos1-snrmask_L1": "38,38,38,38,38,38,38,38,38",
    "pos1-dynamics": "on",
    "pos1-tidecorr": "0",
    "pos1-ionoopt": "brdc",
    "pos1-tropopt": "saas",
    "pos1-sateph": "brdc",
    "pos1-exclsats": "",
    # GPS + GLONASS + Galileo + BeiDou: each is used when the observation and navigation files
    # have it (a LEA-6T gives GPS only, an M8/F9 base adds the rest). SBAS is left out (M8T: in):
    # our navigation files carry no SBAS messages, so a GEO satellite has no orbit to use.
    "pos1-navsys": "45",
    "pos2-armode": "fix-and-hold",
    # GLONASS AR "on" (M8T: fix-and-hold). On the real 2018-10-09 M8P flight (convbin RINEX, the
    # rest of this table) fix-and-hold fixed 1100 epochs and disagreed with RTKLIB's reference by
    # 1.1 m at p95; "on" fixed 1856 and agreed to 1.7 cm. A LEA-6T rover has no GLONASS anyway.
    "pos2-gloarmode": "on",
    "pos2-bdsarmode": "off",
    "pos2-arfilter": "on",
    "pos2-arthres": "3",
    "pos2-arthresmin": "3",
    "pos2-arthresmax": "3",
    "pos2-arthres1": "0.1",
    "pos2-arthres2": "0",
    "pos2-arthres3": "1e-05",
    "pos2-arthres4": "0.0001",
    "pos2-arlockcnt": "0",
    "pos2-minfixsats": "4",
    "pos2-minholdsats": "5",
    "pos2-mindropsats": "10",
    "pos2-varholdamb": "0.1",
    "pos2-gainholdamb": "0.01",
    "pos2-arelmask": "15",
    "pos2-arminfix": "20",
    "pos2-armaxiter": "1",
    "pos2-elmaskhold": "15",
    "pos2-aroutcnt": "20",
    "pos2-maxage": "30",
    "pos2-syncsol": "off",
    "pos2-slipthres": "0.05",
    # Innovation limits at demo5's built-in 5 m / 30 m (M8T: 1 m / 10 m): after a radio gap the
    # predicted phase can be off by more than a metre, and with 1 m demo5 dropped whole epochs of
    # the real 2018-10-09 flight (2034 of 2052 kept) and fixed worse (2.9 cm vs 1.6 cm at p95
    # against the reference).
    "pos2-rejionno": "5",
    "pos2-rejcode": "30",
    "pos2-dopthres": "0",
    "pos2-niter": "1",
    "pos2-baselen": "0",
    "pos2-basesig": "0",
    **OUTPUT_OPTIONS,
    # The header lists the processing options, so every .pos says how it was made.
    "out-outopt": "on",
    "out-outvel": "off",
    "out-degform": "deg",
    "out-outsingle": "off",
    "out-maxsolstd": "0",
    "out-height": "ellipsoidal",
    "out-geoid": "internal",
    "out-solstatic": "all",
    "out-nmeaintv1": "0",
    "out-nmeaintv2": "0",
    # No residual file (M8T: residual): nothing downstream reads it.
    "out-outstat": "off",
    "stats-eratio1": "300",
    "stats-errphase": "0.003",
    "stats-errphaseel": "0.003",
    "stats-errphasebl": "0",
    "stats-errdoppler": "1",
    "stats-snrmax": "52",
    "stats-errsnr": "0",
    "stats-errrcv": "0",
    "stats-stdbias": "30",
    "stats-stdiono": "0.03",
    "stats-stdtrop": "0.3",
    # Acceleration process noise 0.3 / 0.05 m/s^2 horizontal / vertical (M8T: 3 / 1; demo5's
    # built-in: 0.1 / 0.01). RTKLIB lets the acceleration wander as a random walk of this many
    # m/s^2 per sqrt(s): it must cover what the vehicle does, and no more (looser, the real
    # walk below agrees less with RTKLIB's reference). Measured (2026-11-22; commands in
    # benchmarks/RESULTS.md):
    # - simulated multicopter (seed profile, severity 1, 3 seeds of 1200 s, jerk-limited legs,
    #   continuous ionosphere), in-flight fixed / fixes > 10 cm from the truth:
    #   0.3 / 0.05 and 0.1 / 0.05: 100 % / 0 on every seed tried. 0.3 / 0.03 and 0.1 / 0.03:
    #   100 % / 0, 7 (seeds 1, 2; the descent: 10-13 cm vertical). 0.1 / 0.02: 99.3 % / 6 (seed
    #   1). 0.3 / 0.01 and 0.1 / 0.01: 95 % / 25 (climb and descent, up to 16 cm vertical): the
    #   climb's 0.5 m/s^2 (a real multicopter does 1-2) is beyond a filter that expects 0.01
    #   m/s^2 per sqrt(s).
    # - real 2018-10-09 M8P rover (a walk: < 1.8 m/s, < 1 m/s^2, 3.6 m of height), convbin's
    #   RINEX, fixed epochs / p95 distance to RTKLIB's reference where both are fixed:
    #   0.3 / 0.05: 1831 / 2.47 cm; 0.3 / 0.03: 1826 / 2.38 cm; 0.1 / 0.05: 2.59 cm;
    #   0.1 / 0.01: 1856 / 1.72 cm (the reference's own values: it was made with demo5's
    #   built-in options, forward only; 0.05 / 0.01: 2.01 cm, 0.2 / 0.01: 2.20 cm, 0.1 / 0.02:
    #   2.15 cm).
    # No single pair gives both the 2 cm agreement and a clean multicopter flight; the vertical
    # 0.01 that the walk likes cannot follow a climb. So these two are only the constant the
    # solve starts from: run_engine's "dynamics" stage (engine/dynamics.py) replaces them by
    # values derived from the rover's observed accelerations (walk: 0.16 / 0.013, 1826 fixed,
    # 1.95 cm; simulated multicopter: 0.33 / 0.06, no wrong fix), unless the user set them.
    # The forward pass that measures runs with them; they stay in force where nothing can be
    # measured (a pass with too few fixes) and as the lower bound when the pass saw under 75 %
    # of the flight. 0.3 / 0.05 keeps the
    # multicopter safe, the platform this default is for.
    "stats-prnaccelh": "0.3",
    "stats-prnaccelv": "0.05",
    "stats-prnbias": "0.0001",
    "stats-prniono": "0.001",
    "stats-prntrop": "0.0001",
    "stats-prnpos": "0",
    "stats-clkstab": "5e-12",
    # The rover moves: its a-priori position comes from its own single-point solution, not from
    # a RINEX header written on the ground (M8T: rinexhead).
    "ant1-postype": "single",
    "ant1-antdele": "0",
    "ant1-antdeln": "0",
    "ant1-antdelu": "0",
    # The base position is always given (--base-xyz) and replaces these.
    "ant2-postype": "rinexhead",
    "ant2-antdele": "0",
    "ant2-antdeln": "0",
    "ant2-antdelu": "0",
    "ant2-maxaveep": "1",
    "ant2-initrst": "off",
    "misc-timeinterp": "off",
    "misc-sbasatsel": "0",
}
"""demo5 options for a u-blox L1 receiver at 5 Hz (see the comments for the LEA-6T changes)."""


# Debian's rnx2rtkp (2.4.3 b34) has none of demo5's AR controls; these are the settings the
# project used with it so far (GPS L1, fix-and-hold, combined), restricted to keys b34 knows.
B34_L1_KINEMATIC: dict[str, str] = {
    "pos1-posmode": "kinematic",
    "pos1-frequency": "l1",
    "pos1-soltype": "combined",
    "pos1-elmask": "15",
    "pos1-navsys": "1",
    "pos1-tropopt": "saas",
    "pos1-ionoopt": "brdc",
    "pos1-sateph": "brdc",
    "pos2-armode": "fix-and-hold",
    "pos2-arthres": "3.0",
    "pos2-arlockcnt": "5",
    "pos2-arelmask": "15",
    **OUTPUT_OPTIONS,
    "out-outopt": "on",
}
"""rnx2rtkp 2.4.3 b34 options (the former ``RTKLIB_L1_KINEMATIC`` without the non-key
``pos1-ephem``)."""
