"""``groundstation router``: a Zenoh router in this process, configured from the project's TOML.

It owns the translation of :class:`~groundstation.config.RouterSettings` into Zenoh's own
configuration (listen and connect endpoints, the ``transport/link/tls`` table, the
``access_control`` rules, subjects and policies); :mod:`groundstation.bus` opens the session.
No ``zenohd`` binary is needed: eclipse-zenoh runs in router mode.

Access control (``access.enabled``) denies everything by default and allows, by certificate
common name (Zenoh matches the CN of the client certificate of a ``tls/`` link with mutual TLS):

- a station: writes (put, delete, queryable, reply, liveliness token) only
  ``groundstation/<its name>/**``, and is asked (queries, subscriber interest) only there;
- a solver: reads every station (subscribe, query, liveliness) and writes only
  ``groundstation/*/solution`` and ``groundstation/*/rtk`` (the live engine, ``groundstation
  rtk``, runs with a solver's certificate) (and answers ``groundstation/*/q/solution``), and
  claims jobs
  with liveliness tokens on ``groundstation/solvers/claim/**``;
- a viewer: reads every station;
- with ``access.local``, plain TCP over the loopback interface (the daemons and views on this
  machine): everything under ``groundstation/**``.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

from groundstation.bus import KEY_ROOT, open_session
from groundstation.config import RouterSettings, ZenohSettings
from groundstation.errors import GroundstationError

log = logging.getLogger("groundstation.router")

ALL = f"{KEY_ROOT}/**"
WRITE = ["put", "delete", "declare_queryable", "reply", "liveliness_token"]
"""What a writer sends in (ingress)."""
READ = ["declare_subscriber", "query", "declare_liveliness_subscriber", "liveliness_query"]
"""What a reader sends in (ingress)."""
DELIVER = ["put", "delete", "reply", "liveliness_token", "declare_queryable",
           "declare_subscriber"]
"""What the router sends out to a reader (egress): data and the declarations it matches."""
ASKED = ["query", "declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"]
"""What the router sends out to a writer (egress): the interest that makes it publish, and
queries for its queryables."""


def _rule(rule_id: str, flow: str, messages: list[str], key_exprs: list[str]) -> dict[str, Any]:
    return {"id": rule_id, "permission": "allow", "flows": [flow], "messages": messages,
            "key_exprs": key_exprs}


def access_control(settings: RouterSettings) -> dict[str, Any]:
    """Zenoh's ``access_control`` table for the settings' ``[access]`` and ``[stations.*]``."""
    access = settings.access
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []

    def grant(subject_id: str, subject: dict[str, Any], granted: list[dict[str, Any]]) -> None:
        subjects.append({"id": subject_id, **subject})
        rules.extend(granted)
        policies.append({"rules": [r["id"] for r in granted], "subjects": [subject_id]})

    if access.local:
        # loopback AND plain tcp: a tls/ link over loopback is a remote party by its certificate
        grant("local", {"interfaces": ["lo"], "link_protocols": ["tcp"]}, [
            _rule("local-in", "ingress", sorted(set(WRITE + READ)), [ALL]),
            _rule("local-out", "egress", sorted(set(DELIVER + ASKED)), [ALL]),
        ])
    for name, cns in sorted(access.stations.items()):
        own = [f"{KEY_ROOT}/{name}/**"]
        grant(f"station-{name}", {"cert_common_names": list(cns)}, [
            _rule(f"station-{name}-write", "ingress", WRITE, own),
            _rule(f"station-{name}-asked", "egress", ASKED, own),
        ])
    if access.solvers:
        # the solver's results, and the live engine's positions (groundstation rtk)
        solution = [f"{KEY_ROOT}/*/solution", f"{KEY_ROOT}/*/rtk"]
        claims = [f"{KEY_ROOT}/solvers/claim/**"]
        grant("solvers", {"cert_common_names": list(access.solvers)}, [
            _rule("solvers-read", "ingress", READ, [ALL]),
            _rule("solvers-deliver", "egress", DELIVER, [ALL]),
            _rule("solvers-write", "ingress", ["put", "delete"], solution),
            _rule("solvers-serve", "ingress", ["declare_queryable", "reply"],
                  [f"{KEY_ROOT}/*/q/solution"]),
            # the workers' claims (solve/claims.py): a token each, seen by the other workers
            _rule("solvers-claim", "ingress", ["liveliness_token"], claims),
            _rule("solvers-asked", "egress", ASKED,
                  solution + [f"{KEY_ROOT}/*/q/solution"] + claims),
        ])
    if access.viewers:
        grant("viewers", {"cert_common_names": list(access.viewers)}, [
            _rule("viewers-read", "ingress", READ, [ALL]),
            _rule("viewers-deliver", "egress", DELIVER, [ALL]),
        ])
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": subjects, "policies": policies}


def zenoh_extra(settings: RouterSettings) -> dict[str, Any]:
    """Config paths beyond :class:`~groundstation.config.ZenohSettings`: TLS and access."""
    extra: dict[str, Any] = {}
    tls = settings.tls
    if tls.certificate is not None:
        table: dict[str, Any] = {"listen_certificate": str(tls.certificate),
                                 "listen_private_key": str(tls.private_key),
                                 "enable_mtls": tls.mtls}
        if tls.ca is not None:
            table["root_ca_certificate"] = str(tls.ca)
        extra["transport/link/tls"] = table
    if settings.access.enabled:
        extra["access_control"] = access_control(settings)
    return extra


def run_router(settings: RouterSettings, stop: threading.Event) -> None:
    """Route until ``stop`` is set.

    Raises:
        GroundstationError: the router could not start (an endpoint taken, a bad certificate).
    """
    from groundstation.bus import error_text

    zs = ZenohSettings(mode="router", listen=settings.listen, connect=settings.connect,
                       scouting=settings.scouting)
    try:
        session = open_session(zs, zenoh_extra(settings))
    except Exception as err:  # zenoh's own error type
        raise GroundstationError(f"cannot start the router (listen {list(settings.listen)}): "
                                 f"{error_text(err)}") from err
    access = settings.access
    log.info("router listening on %s%s; access control %s", ", ".join(settings.listen),
             f", connecting to {', '.join(settings.connect)}" if settings.connect else "",
             f"on ({len(access.stations)} stations, {len(access.solvers)} solver names)"
             if access.enabled else "off")
    try:
        stop.wait()
    finally:
        session.close()
        log.info("router stopped")
