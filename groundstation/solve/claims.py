"""Several solver workers sharing the sessions: each job claimed by one, solved once.

A job is one recording of a finished session, named by ``(station, session_id, file name)``
(:func:`job_key`). Every worker hears every ``session`` message; before solving a job a worker
claims it (:meth:`Claims.acquire`):

1. The job is done if a final ``solution`` (``ok``, ``failed``, ``skipped``, ``refused``) of it
   has been heard or is answered by ``q/solution`` (when some solver serves it), or an ``ok`` is
   recorded in its output directory (``solution.json``, written when it is published; a failed
   job is not recorded, so a restarted worker may try it again). Done: not claimed.
2. A liveliness query on ``groundstation/solvers/claim/<station>/<session>/<file>/*`` shows no
   other claim; then the worker declares its own token there and, after :data:`SETTLE_S` (the
   time a token takes to reach the other workers), queries again. Two claims made at the same
   moment both see both: the smallest worker id keeps the job, the other withdraws.
3. A worker that finds another's claim keeps the job aside. A claim's token disappears with
   its worker's Zenoh session (killed, crashed, link lost): every worker keeping the job aside
   sees the DELETE and, after a random 0-:data:`RECLAIM_MAX_S` s (so they do not all try at
   once), hands the job back to its queue, where step 1 and 2 run again. A worker that finished
   withdraws its token after publishing the solution, so the others find the job done.

Outputs are idempotent: a claimed job writes to ``<out_root>/<station>/<recording>`` (not a
fresh ``-2`` directory), so a replacement overwrites a killed worker's partial files.

Only :mod:`groundstation.bus` speaks Zenoh; this module uses its liveliness token, liveliness
query and subscriptions.
"""

from __future__ import annotations

import logging
import random
import re
import secrets
import threading
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from groundstation import jsonio, messages
from groundstation.bus import KEY_ROOT, key

if TYPE_CHECKING:
    from groundstation.bus import Bus

log = logging.getLogger("groundstation.solver")

CLAIM_ROOT = f"{KEY_ROOT}/solvers/claim"
SETTLE_S = 1.0
"""Between declaring a claim and checking for rivals: a token crosses loopback or a LAN in
milliseconds; a second leaves room for a loaded machine."""
RECLAIM_MAX_S = 5.0
"""A vanished claim is taken up again after a random 0..this many seconds."""
FINAL = frozenset({"ok", "failed", "skipped", "refused"})
"""Solution statuses that end a job (``solving`` does not)."""
RECORD_NAME = "solution.json"
"""The published ``ok`` solution, kept in the job's output directory: its local done-record."""
MAX_DONE = 100_000
"""Finished jobs remembered from the bus (the oldest forgotten first)."""

JobKey = tuple[str, str, str]
"""(station, session_id, recording file name)."""

_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]")


def job_key(station: str, session_id: str, flight: str | Path) -> JobKey:
    """A job's name: the file name only, so that workers on other machines agree."""
    return station, session_id, Path(str(flight)).name


def _chunk(text: str) -> str:
    """One Zenoh key chunk: no ``/``, wildcard or special character; never empty."""
    out = _UNSAFE.sub("_", text)
    return out if out and out not in (".", "..") else f"_{out}"


def claim_prefix(job: JobKey) -> str:
    """``groundstation/solvers/claim/<station>/<session>/<file>``."""
    return "/".join((CLAIM_ROOT, *(_chunk(part) for part in job)))


def new_worker_id() -> str:
    """A random worker id (ties go to the smallest)."""
    return f"w{secrets.token_hex(6)}"


class Claims:
    """The claim protocol of one worker (module docstring).

    Args:
        bus: the worker's open bus.
        requeue: hands a job kept aside back to the worker's queue (after a claim vanished).
        worker: this worker's id (random by default).
        settle_s: wait between declaring a claim and looking for rivals.
        reclaim_max_s: the random delay before taking up a vanished claim is in [0, this].
    """

    def __init__(self, bus: Bus, requeue: Callable[[Any], None], *, worker: str | None = None,
                 settle_s: float = SETTLE_S, reclaim_max_s: float = RECLAIM_MAX_S) -> None:
        self.bus = bus
        self.worker = worker or new_worker_id()
        self._requeue = requeue
        self.settle_s = settle_s
        self.reclaim_max_s = reclaim_max_s
        self._lock = threading.Lock()
        self._done: dict[JobKey, str] = {}
        self._held: dict[JobKey, Callable[[], None]] = {}
        self._aside: dict[str, tuple[JobKey, Any]] = {}
        """Claim prefix -> a job another worker holds, kept to take it up if that one dies."""
        self._seen: dict[str, set[str]] = {}
        """Claim prefix -> the workers whose claim the liveliness subscription shows now."""
        self._stop = threading.Event()
        self.reclaimed = 0

    def start(self) -> None:
        """Follow the claims and the published solutions."""
        self.bus.subscribe(key("*", "solution"), self._on_solution)
        self.bus.subscribe_liveliness(f"{CLAIM_ROOT}/**", self._on_claim)

    def close(self) -> None:
        """Withdraw every claim still held (a clean stop) and take up nothing more."""
        self._stop.set()
        with self._lock:
            held, self._held = list(self._held.values()), {}
        for withdraw in held:
            withdraw()

    # -- what is done ------------------------------------------------------------------------

    def note_solution(self, station: str, body: Mapping[str, Any]) -> None:
        """A solution message (heard, or published by this worker): a final one ends its job."""
        status = body.get("status")
        if status not in FINAL or not body.get("flight"):
            return
        job = job_key(station, str(body.get("session_id") or ""), str(body["flight"]))
        with self._lock:
            self._done[job] = str(status)
            if len(self._done) > MAX_DONE:  # a flood of solutions must not grow it for ever
                self._done.pop(next(iter(self._done)))
            self._aside.pop(claim_prefix(job), None)

    def record(self, station: str, body: Mapping[str, Any]) -> None:
        """Note a solution this worker publishes; an ``ok`` is also kept in its output
        directory as ``solution.json`` (the done-record a restarted worker reads)."""
        self.note_solution(station, body)
        out = body.get("out_dir")
        if body.get("status") != "ok" or not out:
            return
        try:
            path = Path(str(out)) / RECORD_NAME
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(f".{RECORD_NAME}.{self.worker}")
            tmp.write_bytes(jsonio.dumps({"type": "solution", **body}))
            tmp.replace(path)  # whole or absent, never half a record
        except OSError as err:
            log.warning("could not keep the solution record in %s: %s", out, err)

    def _on_solution(self, key_expr: str, payload: bytes) -> None:
        parts = key_expr.split("/")
        try:
            msg = messages.parse(payload, "solution")
        except messages.BadMessage:
            return
        if len(parts) == 3:
            self.note_solution(parts[1], msg)

    def done(self, job: JobKey, out_dir: Path | None = None) -> str | None:
        """The final status of ``job`` if it is done (heard, answered or recorded)."""
        with self._lock:
            status = self._done.get(job)
        if status is not None:
            return status
        if out_dir is not None:
            status = _recorded(out_dir / RECORD_NAME, job)
            if status is not None:
                return status
        try:  # a solver serving q/solution answers for solutions this worker never heard
            replies = self.bus.get(key(job[0], "q/solution"), timeout_s=1.0)
        except Exception:  # no such queryable, or the link is down: nothing known
            replies = []
        for k, payload in replies:
            try:
                msg = messages.parse(payload, "solution")
            except messages.BadMessage:
                continue
            if (msg.get("status") in FINAL and msg.get("flight")
                    and job_key(k.split("/")[1], str(msg.get("session_id") or ""),
                                str(msg["flight"])) == job):
                return str(msg["status"])
        return None

    # -- claiming ------------------------------------------------------------------------------

    def _claimants(self, job: JobKey) -> set[str]:
        """Who claims ``job``: a liveliness query, and what the subscription has shown (two
        views, so that a reply cut short on a loaded machine does not hide a rival)."""
        prefix = claim_prefix(job)
        got = {k.rsplit("/", 1)[-1] for k in self.bus.liveliness_get(f"{prefix}/*", 2.0)
               if k.startswith(prefix + "/")}
        with self._lock:
            return got | self._seen.get(prefix, set())

    def _aside_job(self, job: JobKey, item: Any) -> None:
        with self._lock:
            self._aside[claim_prefix(job)] = (job, item)

    def acquire(self, job: JobKey, item: Any, out_dir: Path | None = None) -> bool:
        """Claim ``job`` (``item`` is what to hand back to the queue if it must be taken up
        later). ``False``: it is done, or another worker holds it (then it is kept aside)."""
        if self.done(job, out_dir) is not None:
            return False
        others = self._claimants(job) - {self.worker}
        if others:
            log.info("%s: claimed by %s; kept aside", "/".join(job), ", ".join(sorted(others)))
            self._aside_job(job, item)
            return False
        withdraw = self.bus.liveliness_token(f"{claim_prefix(job)}/{self.worker}")
        self._stop.wait(self.settle_s)
        others = self._claimants(job) - {self.worker}
        first = min(others | {self.worker})
        if first != self.worker or self.done(job, out_dir) is not None:
            withdraw()
            if first != self.worker:
                log.info("%s: %s claimed it at the same time and wins", "/".join(job), first)
                self._aside_job(job, item)
            return False
        with self._lock:
            self._held[job] = withdraw
            self._aside.pop(claim_prefix(job), None)
        log.info("%s: claimed (no other claim)", "/".join(job))
        return True

    def release(self, job: JobKey) -> None:
        """Withdraw the claim once the job's solution is published."""
        with self._lock:
            withdraw = self._held.pop(job, None)
        if withdraw is not None:
            withdraw()

    def _on_claim(self, key_expr: str, alive: bool) -> None:
        """A claim appeared or vanished (on a Zenoh thread)."""
        prefix, _, worker = key_expr.rpartition("/")
        with self._lock:
            if alive:
                self._seen.setdefault(prefix, set()).add(worker)
                if len(self._seen) > 10_000:  # only live claims stay; bound it all the same
                    self._seen.pop(next(iter(self._seen)))
            elif prefix in self._seen:
                self._seen[prefix].discard(worker)
                if not self._seen[prefix]:
                    del self._seen[prefix]
        if alive or worker == self.worker or self._stop.is_set():
            return
        with self._lock:
            kept = self._aside.get(prefix)
        if kept is None:
            return
        delay = random.uniform(0.0, self.reclaim_max_s)
        log.info("%s: the claim of %s vanished; taking it up in %.1f s", "/".join(kept[0]),
                 worker, delay)
        timer = threading.Timer(delay, self._take_up, args=(prefix,))
        timer.daemon = True
        timer.start()

    def _take_up(self, prefix: str) -> None:
        with self._lock:
            kept = self._aside.pop(prefix, None)
        if kept is None or self._stop.is_set():
            return
        job, item = kept
        if self.done(job) is not None:
            return
        self.reclaimed += 1
        self._requeue(item)


def _recorded(path: Path, job: JobKey) -> str | None:
    """The status kept in a ``solution.json`` for exactly this job, if any."""
    try:
        msg = messages.parse(path.read_bytes(), "solution")
    except (OSError, messages.BadMessage):
        return None
    station = str(msg.get("station") or "")
    if msg.get("status") == "ok" and msg.get("flight") and job_key(
            station, str(msg.get("session_id") or ""), str(msg["flight"])) == job:
        return str(msg["status"])
    return None
