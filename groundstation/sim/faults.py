"""Radio-link and trigger faults: timed clean messages in, damaged byte chunks and a fault log out.

Mark faults act on the message list (the receiver missed an edge, or sent a mark twice). Link
faults act on bytes as the radio would: bursty dropouts remove every byte whose transmission time
falls inside the outage (cutting frames anywhere), single bytes get corrupted, and frames get cut
short. Everything is drawn from one seeded generator, so a seed reproduces the same damage.

The log says exactly what a correct framer must report: how many frames survive intact, how many
sync words lie in damaged bytes (each is one damaged-frame count for a resynchronising framer),
which epochs (RXM-RAW, or RXM-RAWX in a replayed u-blox 8 recording) and which TIM-TM2 marks did
not arrive intact.
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from groundstation.errors import ConfigError
from groundstation.sim.messages import TimedMessage

DEFAULT_BAUD = 115_200
EPOCH_MESSAGES = ("RXM-RAW", "RXM-RAWX")
"""The messages that carry a measurement epoch (their ``tag`` is the epoch's time of week, ms)."""


@dataclass(frozen=True, slots=True)
class FaultConfig:
    """Fault rates. Rates are per minute of stream; probabilities per mark.

    Attributes:
        dropout_per_min: outages of the radio link.
        dropout_median_s: median outage length (log-normal, so a few are long).
        dropout_max_s: longest outage.
        flight_dropout_per_min: further outages per minute of flight only (the copter far away,
            the channel shared), on top of ``dropout_per_min``.
        dropout_spacing_s: shortest time between the end of one outage and the next.
        corrupt_per_min: frames with one corrupted byte.
        truncate_per_min: frames cut short (the rest of the frame never arrives).
        missed_mark_prob: marks the receiver does not report (its count still increments).
        duplicate_mark_prob: marks reported twice.
    """

    dropout_per_min: float = 0.0
    dropout_median_s: float = 0.3
    dropout_max_s: float = 3.0
    flight_dropout_per_min: float = 0.0
    dropout_spacing_s: float = 0.0
    corrupt_per_min: float = 0.0
    truncate_per_min: float = 0.0
    missed_mark_prob: float = 0.0
    duplicate_mark_prob: float = 0.0

    @classmethod
    def none(cls) -> FaultConfig:
        return cls()

    @classmethod
    def default(cls) -> FaultConfig:
        """Roughly the link of the field report: frequent short outages, some damage."""
        return cls(
            dropout_per_min=2.0,
            corrupt_per_min=1.0,
            truncate_per_min=0.5,
            missed_mark_prob=0.02,
            duplicate_mark_prob=0.02,
        )

    @classmethod
    def seed(cls) -> FaultConfig:
        """The field report's failed flight: about 300 gaps in 20 min of flight, median 0.4 s,
        none longer than 3 s, none on the ground; otherwise the default's damage."""
        return cls(
            dropout_median_s=0.33,
            dropout_max_s=2.8,
            flight_dropout_per_min=21.0,
            dropout_spacing_s=0.5,
            corrupt_per_min=0.2,
            truncate_per_min=0.1,
            missed_mark_prob=0.02,
            duplicate_mark_prob=0.02,
        )

    @property
    def enabled(self) -> bool:
        return any(getattr(self, f.name) for f in fields(self) if f.name.endswith(("min", "prob")))

    @classmethod
    def load(cls, spec: str) -> FaultConfig:
        """``none``, ``default``, ``seed``, or a TOML/JSON file with any of the attribute names."""
        if spec == "none":
            return cls.none()
        if spec == "default":
            return cls.default()
        if spec == "seed":
            return cls.seed()
        path = Path(spec)
        if path.exists() and not path.is_file():  # a FIFO or a device would block
            raise ConfigError("faults", f"{spec} is not a regular file")
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as err:
            raise ConfigError("faults", f"cannot read {spec}: {err}") from err
        try:
            data: dict[str, Any] = (
                json.loads(text) if path.suffix.lower() == ".json" else tomllib.loads(text)
            )
        except (ValueError, tomllib.TOMLDecodeError) as err:
            raise ConfigError("faults", f"{spec}: {err}") from err
        data = data.get("faults", data) if isinstance(data, dict) else data
        if not isinstance(data, dict):
            raise ConfigError("faults", f"{spec}: expected a table of fault settings")
        known = {f.name for f in fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise ConfigError(f"faults.{sorted(unknown)[0]}", "unknown fault setting")
        try:
            values = {k: float(v) for k, v in data.items()}
        except (TypeError, ValueError) as err:
            raise ConfigError("faults", f"{spec}: {err}") from err
        bad = sorted(k for k, v in values.items() if not math.isfinite(v) or v < 0)
        if bad:
            raise ConfigError(f"faults.{bad[0]}", f"must be a finite number >= 0, got "
                                                  f"{data[bad[0]]!r}")
        try:
            return cls(**values)
        except (TypeError, ValueError) as err:
            raise ConfigError("faults", f"{spec}: {err}") from err


@dataclass(slots=True)
class FaultLog:
    """What was injected and what a framer should therefore see."""

    faults: list[dict[str, Any]] = field(default_factory=list)
    frames_sent: int = 0
    frames_intact: int = 0
    frames_damaged: int = 0
    frames_lost: int = 0
    damaged_by_type: dict[str, int] = field(default_factory=dict)
    sync_words_in_damage: int = 0
    bytes_sent: int = 0
    bytes_delivered: int = 0
    epochs_lost_tow_ms: list[int] = field(default_factory=list)
    marks_lost_in_link: list[int] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def apply_mark_faults(
    messages: list[TimedMessage], config: FaultConfig, rng: np.random.Generator
) -> tuple[list[TimedMessage], list[dict[str, Any]]]:
    """Drop (missed) or repeat (duplicate) the TIM-TM2 messages of some marks."""
    out: list[TimedMessage] = []
    log: list[dict[str, Any]] = []
    decided: dict[int, str] = {}
    for msg in messages:
        if msg.name != "TIM-TM2":
            out.append(msg)
            continue
        fate = decided.get(msg.tag)
        if fate is None:
            r = rng.random()
            if r < config.missed_mark_prob:
                fate = "missed"
            elif r < config.missed_mark_prob + config.duplicate_mark_prob:
                fate = "duplicate"
            else:
                fate = "ok"
            decided[msg.tag] = fate
            if fate != "ok":
                log.append({"kind": f"{fate}_mark", "t_gps_ns": msg.t_gps_ns, "count": msg.tag})
        if fate == "missed":
            continue
        out.append(msg)
        if fate == "duplicate":
            out.append(msg)
    return out, log


def _dropouts(
    t0_ns: int, t1_ns: int, config: FaultConfig, rng: np.random.Generator,
    per_min: float | None = None,
) -> list[tuple[int, int]]:
    rate = config.dropout_per_min if per_min is None else per_min
    if rate <= 0:
        return []
    out: list[tuple[int, int]] = []
    t = float(t0_ns)
    mean_gap_ns = 60e9 / rate
    while True:
        t += rng.exponential(mean_gap_ns)
        if t >= t1_ns:
            return out
        dur = min(config.dropout_max_s, config.dropout_median_s * float(rng.lognormal(0, 0.8)))
        end = t + max(dur, 0.02) * 1e9
        if end > t1_ns and per_min is not None:
            return out  # a flight outage ends in flight
        out.append((int(t), int(end)))
        t += dur * 1e9 + config.dropout_spacing_s * 1e9


def apply_link_faults(
    messages: list[TimedMessage],
    config: FaultConfig,
    rng: np.random.Generator,
    baud: int = DEFAULT_BAUD,
    flight_ns: tuple[int, int] | None = None,
    span_ns: tuple[int, int] | None = None,
) -> tuple[list[tuple[int, bytes]], FaultLog]:
    """Damage the byte stream; returns ``(t_gps_ns, chunk)`` pieces in order and the log.

    Each message's bytes leave the UART at ``t_gps_ns + i * 10 / baud`` seconds; a byte sent
    during an outage is lost. ``flight_ns`` (take-off, landing) is where the
    ``flight_dropout_per_min`` outages fall. ``span_ns`` is where the ``dropout_per_min``
    outages fall and what the per-minute rates count (default: the first message to a second
    after the last). The outages are drawn first: with the same span and the generator in the
    same state, two streams of the same data (RXM-RAW or RXM-RAWX) get the same outages.
    """
    log = FaultLog()
    if not messages:
        return [], log
    byte_ns = 10 * 1_000_000_000 / baud
    t0, t1 = span_ns if span_ns is not None else (
        messages[0].t_gps_ns, messages[-1].t_gps_ns + 1_000_000_000)
    dropouts = _dropouts(t0, t1, config, rng)
    if flight_ns is not None and config.flight_dropout_per_min > 0:
        # Sorted by start; a flight profile sets dropout_per_min = 0, so they do not overlap.
        dropouts = sorted(dropouts + _dropouts(*flight_ns, config, rng,
                                               per_min=config.flight_dropout_per_min))
    minutes = (t1 - t0) / 60e9
    n_msgs = len(messages)
    corrupt = _pick(rng, n_msgs, config.corrupt_per_min * minutes)
    truncate = _pick(rng, n_msgs, config.truncate_per_min * minutes)
    drop_logs: list[dict[str, Any]] = [
        {"kind": "dropout", "start_gps_ns": a, "end_gps_ns": b, "bytes_lost": 0,
         "frames_hit": 0, "epochs_lost_tow_ms": [], "marks_lost": []}
        for a, b in dropouts
    ]
    starts = np.array([a for a, _ in dropouts], dtype=np.int64)
    chunks: list[tuple[int, bytes]] = []
    out = bytearray()
    intact_spans: list[tuple[int, int]] = []
    damaged_types: dict[str, int] = {}
    di = 0
    for idx, msg in enumerate(messages):
        raw = bytearray(msg.raw)
        n = len(raw)
        log.frames_sent += 1
        log.bytes_sent += n
        keep = np.ones(n, dtype=bool)
        damaged = False
        t_bytes = msg.t_gps_ns + (np.arange(n) * byte_ns).astype(np.int64)
        # Dropouts overlapping this message.
        while di < len(dropouts) and dropouts[di][1] <= msg.t_gps_ns:
            di += 1
        k = di
        while k < len(dropouts) and starts[k] <= t_bytes[-1]:
            a, b = dropouts[k]
            hit = (t_bytes >= a) & (t_bytes < b)
            if hit.any():
                keep &= ~hit
                damaged = True
                entry = drop_logs[k]
                entry["bytes_lost"] += int(hit.sum())
                entry["frames_hit"] += 1
                if msg.name in EPOCH_MESSAGES:
                    entry["epochs_lost_tow_ms"].append(msg.tag)
                if msg.name == "TIM-TM2":
                    entry["marks_lost"].append(msg.tag)
            k += 1
        if idx in truncate and n > 2:
            cut = int(rng.integers(1, n))
            if keep[cut:].any():
                keep[cut:] = False
                damaged = True
                log.faults.append({"kind": "truncation", "t_gps_ns": msg.t_gps_ns,
                                   "message": msg.name, "tag": msg.tag, "kept_bytes": cut,
                                   "frame_bytes": n})
        if idx in corrupt:
            pos = int(rng.integers(0, n))
            if keep[pos]:
                raw[pos] ^= int(rng.integers(1, 256))
                damaged = True
                log.faults.append({"kind": "corruption", "t_gps_ns": int(t_bytes[pos]),
                                   "message": msg.name, "tag": msg.tag, "offset": pos})
        if not damaged:
            intact_spans.append((len(out), len(out) + n))
            out += raw
            chunks.append((msg.t_gps_ns, bytes(raw)))
            log.frames_intact += 1
            continue
        damaged_types[msg.name] = damaged_types.get(msg.name, 0) + 1
        if not keep.any():
            log.frames_lost += 1
        else:
            log.frames_damaged += 1
        if msg.name in EPOCH_MESSAGES:
            log.epochs_lost_tow_ms.append(msg.tag)
        if msg.name == "TIM-TM2":
            log.marks_lost_in_link.append(msg.tag)
        # Emit the surviving runs as separate chunks at their own transmission times.
        kept = np.flatnonzero(keep)
        if kept.size:
            breaks = np.flatnonzero(np.diff(kept) > 1) + 1
            for run in np.split(kept, breaks):
                piece = bytes(raw[run[0] : run[-1] + 1])
                out += piece
                chunks.append((int(t_bytes[run[0]]), piece))
    log.faults.extend(e for e in drop_logs if e["bytes_lost"])
    log.faults.sort(key=lambda f: f.get("t_gps_ns", f.get("start_gps_ns", 0)))
    log.damaged_by_type = damaged_types
    log.bytes_delivered = len(out)
    log.sync_words_in_damage = _syncs_outside(bytes(out), intact_spans)
    return chunks, log


def _pick(rng: np.random.Generator, n: int, expected: float) -> set[int]:
    """A Poisson number (mean ``expected``) of distinct message indices."""
    if expected <= 0:
        return set()
    k = min(n, int(rng.poisson(expected)))
    return {int(i) for i in rng.choice(n, size=k, replace=False)}


def _syncs_outside(data: bytes, intact: list[tuple[int, int]]) -> int:
    """Sync words (B5 62) that do not start an intact frame and are not inside one."""
    count = 0
    span_i = 0
    pos = data.find(b"\xb5\x62")
    n = len(data)
    while pos >= 0:
        while span_i < len(intact) and intact[span_i][1] <= pos:
            span_i += 1
        inside = span_i < len(intact) and intact[span_i][0] <= pos < intact[span_i][1]
        if not inside and pos + 1 < n:
            count += 1
        pos = data.find(b"\xb5\x62", pos + 1)
    return count
