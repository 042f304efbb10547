"""How the user ran this program: the command that every hint line (``next: ...``, "watch it
from another terminal: ...", the ``--help`` examples) prints, so that a line pasted verbatim
into the same shell runs.

A user who followed the README's quick start ran ``.venv/bin/groundstation demo`` without
activating the venv: a hint saying ``groundstation solve ...`` would then exit 127 ("command
not found"). The rule (:func:`program`):

- run as the ``groundstation`` script: ``groundstation`` when ``PATH`` finds this same script,
  else the path it was run by (``.venv/bin/groundstation``);
- run as ``python -m groundstation.cli``: that, with the interpreter by its name when ``PATH``
  finds this same interpreter, else by its path;
- anything else (embedded, tests calling ``main()``): ``groundstation``.
"""

from __future__ import annotations

import re
import shlex
import shutil
import sys
from pathlib import Path

NAME = "groundstation"
MODULE = "groundstation.cli"


def _same_file(a: str | None, b: str) -> bool:
    if a is None:
        return False
    try:
        return Path(a).resolve() == Path(b).resolve()
    except OSError:
        return False


def _found_as(path: str) -> str:
    """``path`` by its bare name when ``PATH`` finds that same file, else as given (quoted)."""
    name = Path(path).name
    return name if _same_file(shutil.which(name), path) else shlex.quote(path)


def program(argv0: str | None = None, executable: str | None = None) -> str:
    """The command (one or more shell words) that runs this program as the user ran it.

    Args:
        argv0: the program path as run (default ``sys.argv[0]``).
        executable: the Python interpreter (default ``sys.executable``).
    """
    argv0 = sys.argv[0] if argv0 is None else argv0
    executable = sys.executable if executable is None else executable
    base = Path(argv0).name
    if base == NAME and argv0 != NAME:
        return _found_as(argv0)
    if base in ("cli.py", "__main__.py") and Path(argv0).parent.name == NAME and executable:
        return f"{_found_as(executable)} -m {MODULE}"
    return NAME


def command(*args: str) -> str:
    """A command line for a hint: :func:`program` then ``args``, each quoted for the shell
    (``command("solve", "my flight.mcap")`` -> ``groundstation solve 'my flight.mcap'``)."""
    return " ".join([program(), *(shlex.quote(str(a)) for a in args)])


def examples(text: str) -> str:
    """Example lines written with ``groundstation`` (the ``--help`` epilogs) as the user runs
    the program."""
    prog = program()
    if prog == NAME:
        return text
    return re.sub(rf"^(\s*){NAME} ", lambda m: f"{m.group(1)}{prog} ", text, flags=re.M)
