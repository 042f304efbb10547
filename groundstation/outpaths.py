"""Where a command may write: the one check every writer makes before it creates anything.

A writer (``solve --out``, ``rinex -o``, ``simulate --out/--base-out/--truth``, the EXIF copies)
must never replace one of its own inputs nor an existing recording. The rules:

- An output file that exists is refused unless the command was given ``--force``; even then it
  is refused when it is one of the command's inputs or a recording (MCAP, gzip or UBX by
  content), and always when it is a directory.
- An output directory must be a directory (or not exist yet). It is refused when it is, or is
  inside, an input directory (the photos), and when one of the files the writer puts into it
  (``writes``: names relative to the directory, ``name/`` for a whole subdirectory) is one of
  the inputs or an existing recording.

Paths are compared resolved (symbolic links and ``..`` followed), so another spelling of the
same file is the same file. Every refusal is a :class:`~groundstation.errors.ConfigError` naming
the option (exit status 2), raised before anything is created.

After those checks (and the inputs' own), :func:`make_output_dir` creates the directory: one that
cannot be created (``/proc/x``, no permission, a file on the way) is a ``ConfigError`` too.
A writer of single files writes them through :func:`staged_files`: a file that cannot be
created there is a ``ConfigError`` before anything is written, and an existing file is replaced
only by a complete one.

A writer whose outputs are one run's result (``solve``) writes through :func:`staged_output`:
the run fills a fresh staging folder inside the directory and is moved into place only when it
is complete. Until then an earlier result stays whole; a run that fails or is interrupted
leaves nothing of itself. Replacing an earlier result moves away only what is ours: the files
the earlier run listed in its manifest (:data:`MANIFEST_NAME`) and the entries the new run
writes under the same names; anything else in the directory (a user's own files) is untouched.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import shutil
from collections.abc import Collection, Iterable, Iterator, Sequence
from pathlib import Path
from typing import BinaryIO

from groundstation import jsonio
from groundstation.errors import ConfigError, InputError

log = logging.getLogger("groundstation.outpaths")

MANIFEST_NAME = ".groundstation-result.json"
"""Lists (relative to the directory) the files of the run that wrote the directory's result."""
STAGING_PREFIX = ".groundstation-staging-"
"""A run in progress writes into ``<dir>/<prefix><pid>``; moved into place when complete."""
RECORD_SUFFIXES = (".pos", ".json", ".conf", ".html", ".txt")
"""Text records a run may write naming its own files (an engine's input lines, a request):
rewritten at the move to name the final place (:func:`unstaged`)."""
RECORD_MAX_BYTES = 64 << 20
LEGACY_NAMES = ("SOLVE_FAILED.txt",)
"""Notes earlier versions left beside a result; stale once a run completes."""

RECORDING_MAGICS = (b"\x89MCAP0\r\n", b"\x1f\x8b", b"\xb5\x62")
"""First bytes of a recording: MCAP, gzip (``.ubx.gz``), UBX sync."""


def is_recording(path: Path) -> bool:
    """Whether ``path`` is a regular file whose content starts like a recording."""
    try:
        if not path.is_file():
            return False
        with path.open("rb") as f:
            head = f.read(8)
    except OSError:
        return False
    return head.startswith(RECORDING_MAGICS)


def _resolve(path: Path) -> Path:
    """``path.resolve()``, a symbolic link loop refused in one line (Python 3.11 raises
    RuntimeError for it, later versions OSError).

    Raises:
        InputError: the path cannot be resolved.
    """
    try:
        return path.resolve()
    except (RuntimeError, OSError) as err:
        why = "a symbolic link loop" if isinstance(err, RuntimeError) or getattr(
            err, "errno", None) == errno.ELOOP else (getattr(err, "strerror", None) or str(err))
        raise InputError(f"{path}: cannot resolve the path: {why}") from err


def _resolved(paths: Iterable[Path | None]) -> list[tuple[Path, Path]]:
    return [(p, _resolve(p)) for p in paths if p is not None]


def check_output_file(out: Path, inputs: Iterable[Path | None] = (), *, key: str,
                      force: bool = False) -> None:
    """Refuse an output file that would replace an input, a recording, or (without
    ``force``) any existing file.

    Raises:
        ConfigError: naming ``key``.
    """
    o = _resolve(out)
    for given, r in _resolved(inputs):
        if o == r:
            raise ConfigError(key, f"{out} is the input {given}: refusing to replace it")
    if out.is_dir():
        raise ConfigError(key, f"{out} is a directory (expected a file name)")
    if out.exists() or out.is_symlink():
        if is_recording(out):
            raise ConfigError(key, f"{out} is an existing recording: refusing to replace it")
        if not force:
            raise ConfigError(key, f"{out} exists: refusing to overwrite it without --force")
    parent = o.parent
    if not parent.is_dir():
        raise ConfigError(key, f"{out}: directory {parent} does not exist")


def check_output_dir(out_dir: Path, inputs: Iterable[Path | None] = (), *, key: str = "--out",
                     writes: Collection[str] | None = None) -> None:
    """Refuse an output directory that is a file, is (or is inside) an input directory, or
    where a file the writer writes (``writes``) is an input or an existing recording.

    Args:
        out_dir: the directory the writer will create or fill.
        inputs: the command's input files and directories.
        key: the option, for the message.
        writes: names the writer creates in ``out_dir`` (``sub/`` for a whole subdirectory);
            ``None``: any input file inside ``out_dir`` is refused.

    Raises:
        ConfigError: naming ``key``.
    """
    if out_dir.exists() and not out_dir.is_dir():
        raise ConfigError(key, f"{out_dir} is not a directory")
    o = _resolve(out_dir)
    for given, r in _resolved(inputs):
        if o == r or r in o.parents:
            raise ConfigError(key, f"{out_dir} is or is inside the input {given}")
        if r.is_dir() or o not in r.parents:
            continue
        rel = r.relative_to(o).as_posix()
        if writes is None or _written(rel, writes):
            raise ConfigError(key, f"writing into {out_dir} would replace the input {given}")
    for name in writes or ():
        if not name.endswith("/") and is_recording(out_dir / name):
            raise ConfigError(key, f"{out_dir / name} is an existing recording: refusing to "
                                   "replace it")


def make_output_dir(out: Path, key: str = "--out-dir") -> bool:
    """Create the output directory (after every check); True if it did not exist (so that a
    failed run can remove it again).

    Raises:
        ConfigError: naming ``key``: it cannot be created (``/proc/x``, no permission, a file
            on the way).
    """
    if out.is_dir():
        return False
    try:
        out.mkdir(parents=True)
    except OSError as err:
        raise ConfigError(key, f"cannot create {out}: {err.strerror or err}") from err
    return True


@contextlib.contextmanager
def staged_files(outputs: Sequence[tuple[str, Path]]) -> Iterator[list[BinaryIO]]:
    """Open a hidden sibling of each output file (``(option, path)``, after every check) and
    yield them, in order, open for writing.

    A sibling that cannot be created (no permission, ``/proc``, a read-only file system) is a
    :class:`ConfigError` naming its option, and nothing is left of the others: the check that
    the directory is writable is the creation itself. When the block ends normally the
    siblings replace the outputs; on any exception (Ctrl-C too) they are removed and the
    outputs are as they were.

    Raises:
        ConfigError: naming the option of the file that cannot be written.
    """
    opened: list[tuple[Path, Path, BinaryIO]] = []
    try:
        for key, out in outputs:
            tmp = out.with_name(f"{STAGING_PREFIX}{os.getpid()}-{out.name}")
            try:
                handle: BinaryIO = tmp.open("wb")
            except OSError as err:
                raise ConfigError(key, f"cannot write {out}: {err.strerror or err}") from err
            opened.append((tmp, out, handle))
        yield [h for _, _, h in opened]
        for _, _, h in opened:
            h.close()
        for tmp, out, _ in opened:
            os.replace(tmp, out)
    except BaseException:
        for tmp, _, h in opened:
            h.close()
            with contextlib.suppress(OSError):
                tmp.unlink()
        raise


def existing_outputs(out_dir: Path, writes: Iterable[str]) -> list[str]:
    """The names of ``writes`` that already exist in ``out_dir`` (what a run would replace)."""
    return [w for w in writes if (out_dir / w.rstrip("/")).exists()]


@contextlib.contextmanager
def staged_output(out: Path, key: str = "--out-dir") -> Iterator[Path]:
    """Yield a fresh staging folder inside ``out`` (created if need be); when the block ends
    normally its content replaces the earlier result in ``out`` (:func:`_commit`), and on any
    exception (Ctrl-C too) it is removed and ``out`` is as it was (removed if this run created
    it).

    Raises:
        ConfigError: naming ``key``: ``out`` cannot be created.
    """
    created = make_output_dir(out, key)
    stage = out / f"{STAGING_PREFIX}{os.getpid()}"
    # One try from the folder's creation on: a Ctrl-C right after it is made (before a try
    # that began later) left it behind.
    try:
        _remove_stale_stages(out)
        shutil.rmtree(stage, ignore_errors=True)  # a killed run of a recycled pid
        try:
            stage.mkdir()
        except OSError as err:
            raise ConfigError(key, f"cannot write into {out}: {err.strerror or err}") from err
        yield stage
        _commit(stage, out)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        if created:
            with contextlib.suppress(OSError):
                out.rmdir()  # only if empty: nothing but ours could be in it
        raise


def _remove_stale_stages(out: Path) -> None:
    """Remove the staging folders of runs that were killed (SIGKILL, power loss): their
    process is gone. A live run's (two solves into one folder) is left to it."""
    for p in out.glob(f"{STAGING_PREFIX}*"):
        pid = p.name.removeprefix(STAGING_PREFIX).removesuffix(".old")
        if not pid.isdigit() or not p.is_dir() or p.is_symlink():
            continue
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            shutil.rmtree(p, ignore_errors=True)
        except (PermissionError, OverflowError):
            continue  # alive (another user's) or not a pid: not ours to judge


def unstaged(text: str, stage: Path) -> str:
    """``text`` with every path into the staging folder ``stage`` naming the final place (the
    folder's name is unique, so any spelling of the path loses just that component; with
    ``--out-dir .`` the path starts with it)."""
    return text.replace(f"/{stage.name}", "").replace(f"{stage.name}/", "")


def _unstage_records(stage: Path) -> None:
    """Rewrite the run's text records that name the staging folder (:data:`RECORD_SUFFIXES`)."""
    name = stage.name.encode()
    for p in stage.rglob("*"):
        if p.suffix.lower() not in RECORD_SUFFIXES or not p.is_file() or p.is_symlink():
            continue
        if p.stat().st_size > RECORD_MAX_BYTES:
            continue
        data = p.read_bytes()
        if name in data:
            p.write_bytes(data.replace(b"/" + name, b"").replace(name + b"/", b""))


def _commit(stage: Path, out: Path) -> None:
    """Move the complete run in ``stage`` into ``out`` in place of the earlier result.

    File by file, so that a folder of the user's that happens to share a name with one of ours
    (``photos/``) loses nothing but the files this run writes. The earlier result's files (its
    manifest's, and those the new run writes under the same names) are first moved into a
    trash folder beside the stage, then the new files moved in; a failure or Ctrl-C on the way
    moves everything back. Only then is the trash removed.
    """
    _unstage_records(stage)
    files = sorted(p.relative_to(stage).as_posix() for p in stage.rglob("*")
                   if p.is_file() or p.is_symlink())
    old = set(_manifest(out)) | set(files) | set(LEGACY_NAMES) | {MANIFEST_NAME}
    gone = sorted(r for r in old if (out / r).is_file() or (out / r).is_symlink())
    trash = stage.with_name(stage.name + ".old")
    shutil.rmtree(trash, ignore_errors=True)
    moved: list[tuple[Path, Path]] = []  # (from, to), undone in reverse
    made: list[Path] = []  # folders created in out, removed on undo
    wrote_manifest = False
    try:
        for rel in gone:
            dst = trash / rel
            dst.parent.mkdir(parents=True, exist_ok=True)
            (out / rel).rename(dst)
            moved.append((out / rel, dst))
        for rel in files:
            dst = out / rel
            for parent in reversed(Path(rel).parents):
                if parent != Path(".") and not (out / parent).is_dir():
                    (out / parent).mkdir()
                    made.append(out / parent)
            (stage / rel).rename(dst)
            moved.append((stage / rel, dst))
        wrote_manifest = True  # (before the write: a half-written one is ours to remove)
        (out / MANIFEST_NAME).write_bytes(jsonio.dumps({"files": files}))
    except BaseException:
        if wrote_manifest:
            with contextlib.suppress(OSError):
                (out / MANIFEST_NAME).unlink()
        for src, dst in reversed(moved):
            with contextlib.suppress(OSError):
                dst.rename(src)
        for folder in reversed(made):
            with contextlib.suppress(OSError):
                folder.rmdir()
        shutil.rmtree(trash, ignore_errors=True)
        raise
    earlier = [r for r in gone if r != MANIFEST_NAME]
    if earlier:
        log.warning("replacing the earlier result in %s (%d files: %s)", out, len(earlier),
                    ", ".join(earlier[:5]) + (" ..." if len(earlier) > 5 else ""))
    shutil.rmtree(trash, ignore_errors=True)
    shutil.rmtree(stage, ignore_errors=True)  # empty folders only are left in it
    for rel in sorted(gone, key=lambda r: -r.count("/")):  # the earlier run's emptied folders
        for parent in Path(rel).parents:
            if parent != Path("."):
                with contextlib.suppress(OSError):
                    (out / parent).rmdir()  # only if empty: a user's files keep it


def _manifest(out: Path) -> list[str]:
    """The files the earlier run in ``out`` listed (none without a readable manifest); names
    leading out of ``out`` are ignored."""
    try:
        doc = jsonio.loads((out / MANIFEST_NAME).read_bytes())
    except (OSError, ValueError):
        return []
    files = doc.get("files") if isinstance(doc, dict) else None
    if not isinstance(files, list):
        return []
    return [f for f in files if isinstance(f, str) and f and not Path(f).is_absolute()
            and ".." not in Path(f).parts]


def _written(rel: str, writes: Collection[str]) -> bool:
    return any(rel == w or (w.endswith("/") and rel.startswith(w)) for w in writes)
