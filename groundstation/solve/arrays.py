"""The ``.npz`` files of a solve's record (plain NumPy arrays, compressed, never pickled
objects): one writer and one reader, which says in one line what is wrong with a file that is
not what it should be."""

from __future__ import annotations

import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from groundstation.errors import InputError


def write_npz(path: Path, arrays: dict[str, Any]) -> None:
    """Write ``arrays`` (name -> array) to ``path``."""
    with path.open("wb") as f:
        np.savez_compressed(f, **arrays)


def read_npz(path: Path, what: str) -> dict[str, Any]:
    """Every array of ``path`` by name.

    Raises:
        InputError: unreadable, or not a NumPy archive of plain arrays (``what`` names what
            it should hold).
    """
    if not zipfile.is_zipfile(path):  # (a lone .npy array, text, nothing)
        raise InputError(f"{path}: not {what} this program wrote (not a NumPy .npz archive)")
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as err:
        why = "holds objects, not plain arrays" if "pickle" in str(err) else str(err)
        raise InputError(f"{path}: not {what} this program wrote ({why})") from err
