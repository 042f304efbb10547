"""Several recordings of one receiver merged frame by frame (the radio link's recording and an
on-board log, say): each epoch and each mark from whichever copy has it intact, once.

A recording is cut into *epoch blocks*: a measurement epoch (RXM-RAW/RXM-RAWX) and the frames
that follow it up to the next one (time marks, subframes, fixes), all valid frames (a damaged
frame is no frame). The merged stream takes, epoch by epoch in time order, the block with the
most frames, then the frames of the other copies' blocks of that epoch that no chosen block
holds (the same bytes are the same frame, written once: a copy that lost an epoch holds the
frames after it in the block before, where the chosen copy does not). Frames before a copy's
first epoch come first. What each copy supplied is counted for the report.
"""

from __future__ import annotations

import contextlib
import struct
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from groundstation.errors import InputError
from groundstation.gpstime import NS_PER_WEEK
from groundstation.offline.rinex.convert import read_frames

_RXM_RAW, _RXM_RAWX, _TIM_TM2 = (0x02, 0x10), (0x02, 0x15), (0x0D, 0x03)
_BEFORE = -1  # the block of frames before a copy's first epoch


@dataclass(slots=True)
class CopyShare:
    """What one copy brought to the merge."""

    name: str
    epochs: int = 0
    epochs_only_here: int = 0
    marks_only_here: int = 0
    frames_used: int = 0


@dataclass(slots=True)
class MergeReport:
    """The merge: per copy, and in all."""

    copies: list[CopyShare] = field(default_factory=list)
    epochs: int = 0
    frames: int = 0

    def text(self) -> str:
        parts = [f"{c.name}: {c.epochs} epochs ({c.epochs_only_here} only there), "
                 f"{c.marks_only_here} time-mark record(s) only there" for c in self.copies]
        return (f"merged {len(self.copies)} recordings of the receiver into {self.epochs} "
                f"epochs: " + "; ".join(parts))


def _epoch_time(payload: bytes, key: tuple[int, int]) -> int | None:
    try:
        if key == _RXM_RAW:
            itow, week = struct.unpack_from("<iH", payload, 0)
            return week * NS_PER_WEEK + itow * 1_000_000 if week else None
        tow, week = struct.unpack_from("<dH", payload, 0)
        return week * NS_PER_WEEK + round(tow * 1e9) if week else None
    except struct.error:
        return None


def _blocks(path: Path) -> dict[int, list[bytes]]:
    """A copy's frames by epoch block (epoch GPS ns -> frames, the epoch's own first)."""
    data, index = read_frames(path)
    blocks: dict[int, list[bytes]] = {}
    current = _BEFORE
    for s, c, i, n in zip(index.start.tolist(), index.cls.tolist(), index.id.tolist(),
                          index.length.tolist(), strict=True):
        raw = data[s: s + n + 8]
        key = (c, i)
        if key in (_RXM_RAW, _RXM_RAWX):
            t = _epoch_time(raw[6:-2], key)
            if t is not None:
                current = t
        blocks.setdefault(current, []).append(raw)
    return blocks


SAME_SHARE = 0.9
"""The share of the epochs two copies both hold whose measurement frame must be the same bytes
(a copy damaged in places still qualifies: a damaged frame is no frame, so an epoch either
arrived intact or is missing)."""


def _same_receiver(a: tuple[str, dict[int, list[bytes]]],
                   b: tuple[str, dict[int, list[bytes]]]) -> None:
    """Refuse to merge two recordings that are not copies of one receiver's stream: their
    shared epochs' measurement frames must be the same bytes (two receivers never report the
    same pseudoranges to the bit: their clocks alone differ by hundreds of metres).

    Raises:
        InputError: no epoch in common, or different measurements at the shared epochs.
    """
    (na, ba), (nb, bb) = a, b
    shared = [t for t in ba.keys() & bb.keys() if t != _BEFORE]
    if not shared:
        raise InputError(f"{nb}: no epoch in common with {na}: not a copy of the same "
                         "receiver's recording (several recordings are merged as copies of "
                         "one receiver's stream: the radio's and an on-board log)")
    same = sum(ba[t][0] == bb[t][0] for t in shared)
    if same < SAME_SHARE * len(shared):
        raise InputError(f"{nb}: its measurements differ from {na}'s at {len(shared) - same} "
                         f"of the {len(shared)} epochs both hold: another receiver's recording, "
                         "not a copy of the same one (a base goes with --base)")


def merge(paths: Sequence[Path], out: Path) -> MergeReport:
    """Merge the recordings into ``out`` (a ``.ubx`` of valid frames).

    Raises:
        InputError: a copy is unreadable, none has an epoch, or one is not a copy of the
            first (:func:`_same_receiver`).
    """
    copies = [(p.name, _blocks(p)) for p in paths]
    for name, blocks in copies[1:]:
        _same_receiver(copies[0], (name, blocks))
    report = MergeReport([CopyShare(name) for name, _ in copies])
    times = sorted({t for _, b in copies for t in b})
    if not any(t != _BEFORE for t in times):
        raise InputError(f"{', '.join(p.name for p in paths)}: no measurement epoch to merge")
    chosen = {t: max((k for k, (_, b) in enumerate(copies) if t in b),
                     key=lambda k: len(copies[k][1][t])) for t in times}
    in_chosen = {raw for t, k in chosen.items() for raw in copies[k][1][t]}
    seen: set[bytes] = set()
    with out.open("wb") as f:
        for t in times:
            have = [(k, b[t]) for k, (_, b) in enumerate(copies) if t in b]
            have.sort(key=lambda kb: kb[0] != chosen[t])  # the chosen block first
            for k, frames in have:
                share = report.copies[k]
                if t != _BEFORE:
                    share.epochs += 1
                    share.epochs_only_here += len(have) == 1
                for raw in frames:
                    if raw in seen or (k != chosen[t] and raw in in_chosen):
                        continue
                    seen.add(raw)
                    f.write(raw)
                    share.frames_used += 1
                    report.frames += 1
                    if raw[2:4] == bytes(_TIM_TM2) and not any(
                            raw in b for j, b in have if j != k):
                        share.marks_only_here += 1
            if t != _BEFORE:
                report.epochs += 1
    return report


@contextlib.contextmanager
def one_recording(paths: Sequence[Path]) -> Iterator[tuple[Path, MergeReport | None]]:
    """The receiver's recording for a command given one or more copies of it: the one path
    itself (no report), or the copies merged (:func:`merge`) into a temporary ``.ubx`` named
    after the first (``rover_merged.ubx``), removed on leaving. Each copy must hold UBX
    frames (the same one-line error as for one recording).

    Raises:
        InputError: a copy is missing, unreadable or holds no UBX frame; none has an epoch.
    """
    from groundstation.offline.inspect import require_ubx_frames

    if len(paths) == 1:
        yield paths[0], None
        return
    seen: dict[Path, Path] = {}
    for p in paths:
        require_ubx_frames(p)
        first = seen.setdefault(p.resolve(), p)
        if first is not p:
            raise InputError(f"{p}: given twice (as {first} too): nothing to merge it with")
    with tempfile.TemporaryDirectory(prefix="groundstation-merge-") as tmp:
        out = Path(tmp) / f"{paths[0].name.split('.')[0]}_merged.ubx"
        yield out, merge(paths, out)
