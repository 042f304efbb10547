"""The demo5 worker process: the only place that loads ``pyrtklib5`` (RTKLIB demo5 in C).

Run as ``python -m groundstation.solve.engine.worker REQUEST.json RESPONSE.json``. A crash in
C (a segmentation fault, an abort) ends this process only; the caller sees the exit status.
Requests and responses are JSON files, not stdout, because RTKLIB prints to stdout/stderr.

Requests:
    ``{"op": "table"}`` -> ``{"version", "library", "rows": [[name, format, comment], ...]}``
    ``{"op": "postpos", "conf", "inputs", "out", "options_out", "prog"}`` -> ``{"status",
    "version", "options": [[key, value], ...]}``: RTKLIB's ``resetsysopts``, ``loadopts``,
    ``getsysopts`` and ``postpos``, exactly as ``rnx2rtkp -k CONF -o OUT INPUTS...``.
"""

from __future__ import annotations

import importlib.metadata
import sys
from pathlib import Path
from typing import Any

import pyrtklib5 as rtk

from groundstation import jsonio


def version() -> tuple[str, str]:
    """(RTKLIB version, binding version), e.g. ("EX 2.5.0", "pyrtklib5 0.2.8")."""
    try:
        binding = importlib.metadata.version("pyrtklib5")
    except importlib.metadata.PackageNotFoundError:
        binding = "unknown"
    return f"{rtk.VER_RTKLIB} {rtk.PATCH_LEVEL}", f"pyrtklib5 {binding}"


def option_rows() -> list[list[Any]]:
    """demo5's ``sysopts[]``: [name, format, comment] up to the empty-name terminator."""
    rows: list[list[Any]] = []
    table = rtk.sysopts
    # The binding's __len__ is broken for this extern array: walk to the terminator as C does.
    i = 0
    while True:
        opt = table[i]
        name = opt.name.ptr
        if not name:
            return rows
        rows.append([name, int(opt.format), opt.comment.ptr])
        i += 1


def postpos(req: dict[str, Any]) -> dict[str, Any]:
    """Load the options file into the engine's tables and run ``postpos`` on the inputs."""
    conf, out, options_out = str(req["conf"]), str(req["out"]), str(req["options_out"])
    inputs = [str(p) for p in req["inputs"]]
    rtk.resetsysopts()
    if not rtk.loadopts(conf, rtk.sysopts.ptr):
        return {"status": -1, "error": f"cannot read options file {conf}"}
    popt, sopt, fopt = rtk.prcopt_t(), rtk.solopt_t(), rtk.filopt_t()
    rtk.getsysopts(popt, sopt, fopt)
    prog = str(req.get("prog", ""))[:63]
    for k, ch in enumerate(prog):
        sopt.prog[k] = ch
    sopt.prog[len(prog)] = "\0"
    # The full effective option set, every key of the table, as the engine will use it.
    rtk.saveopts(options_out, "w", "", rtk.sysopts.ptr)
    t0 = rtk.gtime_t()  # zero time: no start/end limits, as rnx2rtkp without -ts/-te
    status = rtk.postpos(t0, t0, 0.0, 0.0, popt, sopt, fopt, inputs, len(inputs), out, "", "")
    options: list[list[str]] = []
    for line in Path(options_out).read_text(encoding="ascii", errors="replace").splitlines():
        body = line.split("#", 1)[0]
        if "=" in body:
            key, _, value = body.partition("=")
            options.append([key.strip(), value.strip()])
    ver, lib = version()
    return {"status": int(status), "version": ver, "library": lib, "options": options}


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 2:
        sys.stderr.write("usage: python -m groundstation.solve.engine.worker REQUEST RESPONSE\n")
        return 2
    req = jsonio.loads(Path(args[0]).read_bytes())
    if req.get("op") == "table":
        ver, lib = version()
        resp: dict[str, Any] = {"version": ver, "library": lib, "rows": option_rows()}
    elif req.get("op") == "postpos":
        resp = postpos(req)
    else:
        sys.stderr.write(f"unknown request {req.get('op')!r}\n")
        return 2
    Path(args[1]).write_bytes(jsonio.dumps(resp))
    return 0


if __name__ == "__main__":
    sys.exit(main())
