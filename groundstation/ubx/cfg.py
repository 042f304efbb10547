"""Receiver configuration profiles: TOML data in, validated UBX CFG frames (built by pyubx2) out.

A profile is data, not code: a list of CFG messages, each with its pyubx2 field names and
values (``CFG-VALSET`` takes configuration-database keys instead of fields). The loader checks
every name against pyubx2's own tables before anything is built, because pyubx2 silently ignores
keyword arguments it does not know -- a misspelt ``rateUART1`` would otherwise become a message
that switches the output *off*. Every error is a :class:`ConfigError` naming the offending key.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pyubx2 import SET, UBXMessage
from pyubx2.ubxtypes_configdb import UBX_CONFIG_DATABASE
from pyubx2.ubxtypes_core import UBX_MSGIDS
from pyubx2.ubxtypes_set import UBX_PAYLOADS_SET

from groundstation.errors import ConfigError

ACK_CLASS = 0x05
ACK_ACK_ID = 0x01
ACK_NAK_ID = 0x00
CFG_CLASS = 0x06
CFG_PRT_ID = 0x00
UART1_PORT_ID = 1
VALSET_MAX_KEYS = 64
VALSET_LAYERS: dict[str, int] = {"ram": 1, "bbr": 2, "flash": 4}
"""CFG-VALSET layer names -> bits of the ``layers`` byte."""

PROFILE_KEYS = frozenset({"name", "receiver", "description", "messages"})
MESSAGE_KEYS = frozenset({"name", "comment", "fields"})
VALSET_MESSAGE_KEYS = frozenset({"name", "comment", "layers", "transaction", "keys"})
# The UART1 baud rate keys: when a message sets one, the host must follow it after the ACK.
_VALSET_UART1_BAUD = "CFG_UART1_BAUDRATE"


@dataclass(frozen=True, slots=True)
class CfgMessage:
    """One configuration message, ready to send.

    Attributes:
        index: position in the profile, from 1 (for reports).
        name: pyubx2 identity, e.g. ``"CFG-MSG"`` or ``"CFG-VALSET"``.
        summary: one line saying what the message does, e.g. ``"RXM-RAW on UART1 every 1"``.
        frame: the complete UBX frame (sync word to checksum), as pyubx2 serialises it.
        cls: message class byte (0x06).
        id: message id byte; the ACK-ACK/ACK-NAK carries ``cls`` and ``id``.
        uart1_baud: the UART1 baud rate this message sets (CFG-PRT on port 1, or a VALSET of
            ``CFG_UART1_BAUDRATE`` in the RAM layer); ``None`` if it does not touch it.
    """

    index: int
    name: str
    summary: str
    frame: bytes
    cls: int
    id: int
    uart1_baud: int | None = None

    @property
    def hex(self) -> str:
        """The frame as space-separated hex bytes."""
        return self.frame.hex(" ")


@dataclass(frozen=True, slots=True)
class Profile:
    """A named, validated receiver configuration.

    Attributes:
        name: profile name (the file stem).
        receiver: which receiver and firmware the profile is for.
        description: what the profile sets up, in a sentence or two.
        path: the TOML file it was loaded from.
        messages: the messages in sending order.
    """

    name: str
    receiver: str
    description: str
    path: Path
    messages: tuple[CfgMessage, ...]


def default_profile_dirs() -> tuple[Path, ...]:
    """Where ``--profile NAME`` is looked up: the checkout's ``config/profiles``, then /etc."""
    return (
        Path(__file__).resolve().parents[2] / "config" / "profiles",
        Path("/etc/groundstation/profiles"),
    )


def available_profiles(dirs: Sequence[Path] | None = None) -> list[str]:
    """Names of the profiles found in ``dirs`` (default: :func:`default_profile_dirs`)."""
    names: set[str] = set()
    for d in dirs if dirs is not None else default_profile_dirs():
        if d.is_dir():
            names.update(p.stem for p in d.glob("*.toml"))
    return sorted(names)


def find_profile(name: str, dirs: Sequence[Path] | None = None) -> Path:
    """The TOML file of profile ``name``; ``name`` may also be a path to a ``.toml`` file.

    Raises:
        ConfigError: (key ``profile``) when no such profile exists; the message lists the
            known ones.
    """
    as_path = Path(name)
    if as_path.suffix == ".toml":
        if as_path.is_file():
            return as_path
        raise ConfigError("profile", f"no such profile file: {name}")
    search = list(dirs) if dirs is not None else list(default_profile_dirs())
    for d in search:
        candidate = d / f"{name}.toml"
        if candidate.is_file():
            return candidate
    known = ", ".join(available_profiles(search)) or "none"
    raise ConfigError(
        "profile",
        f"unknown profile {name!r} (known: {known}; searched {', '.join(map(str, search))})",
    )


def load_profile(name: str, dirs: Sequence[Path] | None = None) -> Profile:
    """Find, parse and validate a profile, building every message.

    Raises:
        ConfigError: unknown profile, unreadable TOML, or any invalid key or value (the error's
            ``key`` is a path such as ``messages[2].fields.rateUART1``).
    """
    path = find_profile(name, dirs)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError("profile", f"cannot read {path}: {err}") from err
    except tomllib.TOMLDecodeError as err:
        raise ConfigError("profile", f"{path}: invalid TOML: {err}") from err
    return parse_profile(data, path)


def parse_profile(data: Mapping[str, Any], path: Path) -> Profile:
    """Validate a parsed profile table and build its messages (see :func:`load_profile`)."""
    _no_unknown(data, PROFILE_KEYS, "")
    messages = data.get("messages")
    if not isinstance(messages, list) or not messages:
        raise ConfigError("messages", f"{path}: a profile needs a non-empty [[messages]] list")
    built = []
    for i, spec in enumerate(messages):
        where = f"messages[{i}]"
        if not isinstance(spec, dict):
            raise ConfigError(where, "each message must be a table")
        built.append(build_message(spec, index=i + 1, where=where))
    return Profile(
        name=str(data.get("name", path.stem)),
        receiver=str(data.get("receiver", "")),
        description=str(data.get("description", "")).strip(),
        path=path,
        messages=tuple(built),
    )


def build_message(spec: Mapping[str, Any], *, index: int = 1, where: str = "message") -> CfgMessage:
    """Build one message from its profile table (``name`` plus ``fields`` or VALSET ``keys``).

    Raises:
        ConfigError: unknown message, field or key, or a value pyubx2 refuses.
    """
    name = spec.get("name")
    if not isinstance(name, str):
        raise ConfigError(f"{where}.name", "missing message name (e.g. \"CFG-MSG\")")
    if name == "CFG-VALSET":
        return _build_valset(spec, index, where)
    if not name.startswith("CFG-") or name not in UBX_PAYLOADS_SET:
        raise ConfigError(f"{where}.name", f"{name!r} is not a CFG message pyubx2 can set")
    _no_unknown(spec, MESSAGE_KEYS, where)
    fields = spec.get("fields", {})
    if not isinstance(fields, dict):
        raise ConfigError(f"{where}.fields", "must be a table of field = value")
    types = settable_fields(name)
    kwargs: dict[str, Any] = {}
    for key, value in fields.items():
        if key not in types:
            raise ConfigError(
                f"{where}.fields.{key}",
                f"{name} has no field {key!r} (fields: {', '.join(types)})",
            )
        kwargs[key] = _field_value(value, types[key], f"{where}.fields.{key}")
    try:
        msg = UBXMessage("CFG", name, SET, **kwargs)
        frame = bytes(msg.serialize())
    except Exception as err:  # pyubx2 raises several unrelated types for bad values
        raise ConfigError(where, f"pyubx2 cannot build {name}: {err}") from err
    baud = None
    if name == "CFG-PRT" and fields.get("portID") == UART1_PORT_ID and "baudRate" in fields:
        baud = int(fields["baudRate"])
    return CfgMessage(
        index=index,
        name=name,
        summary=str(spec.get("comment", "")) or _summary(name, fields),
        frame=frame,
        cls=frame[2],
        id=frame[3],
        uart1_baud=baud,
    )


def settable_fields(name: str) -> dict[str, str]:
    """Field name -> pyubx2 type code for a SET message, bit-field members included.

    Members of a bit field get the code ``"bNNN"`` (NNN bits wide) instead of pyubx2's
    ``"UNNN"``, which there counts bits, not bytes. Repeating groups are not supported (no CFG
    message this project needs has one, except CFG-VALSET, built from configuration keys).
    """
    out: dict[str, str] = {}
    for key, typ in UBX_PAYLOADS_SET[name].items():
        if isinstance(typ, tuple):
            if key.endswith("_bit"):
                out.update({k: f"b{v[1:]}" for k, v in typ[1].items()})
            continue  # repeating group
        out[key] = typ
    return out


def _build_valset(spec: Mapping[str, Any], index: int, where: str) -> CfgMessage:
    _no_unknown(spec, VALSET_MESSAGE_KEYS, where)
    layer_names = spec.get("layers", ["ram"])
    if not isinstance(layer_names, list) or not layer_names:
        raise ConfigError(f"{where}.layers", f"a list of layers among {sorted(VALSET_LAYERS)}")
    layers = 0
    for layer in layer_names:
        if layer not in VALSET_LAYERS:
            raise ConfigError(
                f"{where}.layers", f"unknown layer {layer!r} (use {sorted(VALSET_LAYERS)})"
            )
        layers |= VALSET_LAYERS[layer]
    transaction = spec.get("transaction", 0)
    if transaction not in (0, 1, 2, 3):
        raise ConfigError(f"{where}.transaction", "0 none, 1 start, 2 ongoing, 3 commit")
    keys = spec.get("keys")
    if not isinstance(keys, dict) or not keys:
        raise ConfigError(f"{where}.keys", "a non-empty table of CFG_... = value")
    if len(keys) > VALSET_MAX_KEYS:
        raise ConfigError(
            f"{where}.keys", f"{len(keys)} keys; one CFG-VALSET takes at most {VALSET_MAX_KEYS}"
        )
    cfg_data: list[tuple[str, object]] = []
    for key, value in keys.items():
        if key not in UBX_CONFIG_DATABASE:
            raise ConfigError(f"{where}.keys.{key}", "not a configuration key pyubx2 knows")
        typ = UBX_CONFIG_DATABASE[key][1]
        cfg_data.append((key, _field_value(value, typ, f"{where}.keys.{key}")))
    try:
        msg = UBXMessage.config_set(layers, transaction, cfg_data)
        frame = bytes(msg.serialize())
    except Exception as err:  # pyubx2 raises several unrelated types for bad values
        raise ConfigError(where, f"pyubx2 cannot build CFG-VALSET: {err}") from err
    baud = None
    if _VALSET_UART1_BAUD in keys and layers & VALSET_LAYERS["ram"]:
        baud = int(keys[_VALSET_UART1_BAUD])
    summary = str(spec.get("comment", "")) or (
        f"{len(keys)} keys in {'+'.join(layer_names)}"
    )
    return CfgMessage(
        index=index, name="CFG-VALSET", summary=summary, frame=frame,
        cls=frame[2], id=frame[3], uart1_baud=baud,
    )


def _field_value(value: Any, typ: str, key: str) -> Any:
    """Check a TOML value against a pyubx2 type code and convert it as pyubx2 expects."""
    kind, size = typ[0], int(typ[1:])
    if kind == "L":  # configuration-database boolean
        if not isinstance(value, bool):
            raise ConfigError(key, f"expected true or false, got {value!r}")
        return int(value)
    if kind == "R":
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(key, f"expected a number, got {value!r}")
        return float(value)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(key, f"expected an integer, got {value!r}")
    if kind == "I":
        lo, hi = -(1 << (8 * size - 1)), (1 << (8 * size - 1)) - 1
    elif kind == "b":
        lo, hi = 0, (1 << size) - 1
    else:
        lo, hi = 0, (1 << (8 * size)) - 1
    if not lo <= value <= hi:
        raise ConfigError(key, f"{value} does not fit {typ} ({lo}..{hi})")
    if kind == "X":  # whole bit-field words travel as little-endian bytes in pyubx2
        return value.to_bytes(size, "little")
    return value


def _no_unknown(table: Mapping[str, Any], allowed: frozenset[str], where: str) -> None:
    for key in table:
        if key not in allowed:
            full = f"{where}.{key}" if where else key
            raise ConfigError(full, f"unknown key (allowed: {', '.join(sorted(allowed))})")


def _summary(name: str, fields: Mapping[str, Any]) -> str:
    if name == "CFG-MSG" and "msgClass" in fields and "msgID" in fields:
        cls_id = bytes((fields["msgClass"], fields["msgID"]))
        target = UBX_MSGIDS.get(cls_id, f"{cls_id[0]:02X} {cls_id[1]:02X}")
        rates = ", ".join(f"{k[4:]}={v}" for k, v in fields.items() if k.startswith("rate"))
        return f"{target} ({cls_id.hex(' ')}): {rates or 'all ports off'}"
    return ", ".join(f"{k}={v}" for k, v in fields.items())
