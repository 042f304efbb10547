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
"""

from __future__ import annotations

from collections.abc import Collection, Iterable
from pathlib import Path

from groundstation.errors import ConfigError

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


def _resolved(paths: Iterable[Path | None]) -> list[tuple[Path, Path]]:
    return [(p, p.resolve()) for p in paths if p is not None]


def check_output_file(out: Path, inputs: Iterable[Path | None] = (), *, key: str,
                      force: bool = False) -> None:
    """Refuse an output file that would replace an input, a recording, or (without
    ``force``) any existing file.

    Raises:
        ConfigError: naming ``key``.
    """
    o = out.resolve()
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
    o = out_dir.resolve()
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


def _written(rel: str, writes: Collection[str]) -> bool:
    return any(rel == w or (w.endswith("/") and rel.startswith(w)) for w in writes)
