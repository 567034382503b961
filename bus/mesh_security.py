"""Mutual TLS and access control on the Zenoh mesh (SPEC §9), as Zenoh configuration.

With `security.tls`, every link of a node is TLS with both ends showing a certificate
from the fleet CA (`fleet pki`); a node without one, or with one from another CA,
cannot join. A router (the ground, every agent) also enforces access rules by the
certificate's common name, generated from the certificates issued into its PKI
directory (`<name>.pem`, role in the OU):

- a drone (CN = its id; its on-board programs use its certificate) may publish,
  declare and answer only under `drone/<its id>/**`, query `ground/ping` and other
  drones' `ping` (link probes), and may never query any `drone/*/cmd` or
  `drone/*/bundle`;
- a relay (a drone issued `--role relay`) may also carry every other drone's traffic:
  all messages under `drone/**`, both ways, commands and bundles included;
- the ground may do everything; an operator (`fleet sub`, `fleet record`) may only
  subscribe;
- an observer (a ground run `--observer`, SPEC §14: a command post) reads everything,
  asks the grounds for what it missed (queries under `ground/**`), and declares and
  publishes only under `ground/<its name>`: it can neither command a drone, push it a
  bundle, nor speak for another ground (`ground/<id>/active` included).

Zenoh applies these rules per link, to the node at its other end, not to whoever
first sent a message: a router forwarding for others is seen by the next router under
its own name. So a drone whose traffic reaches the ground through a neighbour gets
through only if that neighbour holds a relay certificate — on the ground's router,
which checks the relay's link, and on its own router, which takes the ground's
commands from the relay (measured on the emulated radio, tests/radio/;
ADR 0010). What that lets a relay do: drop or delay what it forwards, read it, and
publish as any drone; it cannot command one — commands and bundles are signed end to end
(schemas/auth.py) and an agent refuses any the ground did not sign. A plain drone can
do none of this, so issue `relay` only to the drones a mission may send as relays.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from dronefleet.schemas.config_loading import Security
from dronefleet.schemas.errors import ConfigError

ALL_MESSAGES = ["put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
                "liveliness_token", "liveliness_query", "declare_liveliness_subscriber"]
READ_MESSAGES = ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"]
BOTH = ["ingress", "egress"]


def _identities(pki_dir: Path) -> dict[str, str]:
    """CN → role (OU) of every node certificate in the directory."""
    from cryptography import x509
    from cryptography.x509.oid import NameOID

    found: dict[str, str] = {}
    for pem in sorted(pki_dir.glob("*.pem")):
        if pem.name == "ca.pem":
            continue
        try:
            cert = x509.load_pem_x509_certificate(pem.read_bytes())
        except ValueError as exc:  # corrupt, or not a certificate
            raise ConfigError(f"security.pki_dir: {pem} is not a PEM certificate ({exc}); "
                              f"issue it again with `fleet pki issue {pki_dir} {pem.stem} --role …`") from None
        cn = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
        ou = cert.subject.get_attributes_for_oid(NameOID.ORGANIZATIONAL_UNIT_NAME)
        if cn and ou:
            found[str(cn[0].value)] = str(ou[0].value)
    return found


def certificate_role(security: Security, name: str) -> str | None:
    """The role (OU) of the certificate this node shows (`security.name`, else `name`) on
    a secured mesh; None when the mesh is not secured or no such certificate is issued."""
    if not security.tls or security.pki_dir is None:
        return None
    return _identities(Path(security.pki_dir).expanduser()).get(security.name or name)


def relays_of(security: Security) -> frozenset[str] | None:
    """The drones whose certificates in the PKI directory make them relays; None when
    the mesh is not secured (no access rules: every drone may carry others' traffic)."""
    if not security.tls:
        return None
    assert security.pki_dir is not None
    return frozenset(cn for cn, role in _identities(Path(security.pki_dir).expanduser()).items() if role == "relay")


def access_control(pki_dir: Path, namespace: str = "", bridges: tuple[str, frozenset[str]] | None = None) -> dict[str, Any]:
    """Zenoh `access_control` for a router, default deny. `bridges` (this drone's name
    and its bridge sessions' ZIDs, agent/neighbours.py): links from those sessions,
    which show this drone's own certificate, carry everything, as a relay's would."""
    prefix = f"{namespace}/" if namespace else ""
    rules: list[dict[str, Any]] = [
        {"id": "all", "permission": "allow", "flows": BOTH, "messages": ALL_MESSAGES, "key_exprs": ["**"]},
        {"id": "read", "permission": "allow", "flows": ["ingress"], "messages": READ_MESSAGES, "key_exprs": ["**"]},
        {"id": "read-out", "permission": "allow", "flows": ["egress"], "messages": ["put", "delete", "liveliness_token", "reply"],
         "key_exprs": ["**"]},
        {"id": "probes", "permission": "allow", "flows": BOTH, "messages": ["query", "reply"],
         "key_exprs": [f"{prefix}ground/ping", f"{prefix}drone/*/ping"]},
        # What the ground (and neighbours) declare must reach a drone's router, or it
        # would not know where to send its own traffic: declarations out, on any key.
        {"id": "learn", "permission": "allow", "flows": ["egress"],
         "messages": ["declare_subscriber", "declare_queryable", "declare_liveliness_subscriber", "liveliness_token",
                      "liveliness_query"], "key_exprs": ["**"]},
        {"id": "ground-state", "permission": "allow", "flows": BOTH,
         "messages": ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query", "liveliness_token", "put",
                      "reply"], "key_exprs": [f"{prefix}ground/**"]},
        {"id": "forward", "permission": "allow", "flows": BOTH, "messages": ALL_MESSAGES,
         "key_exprs": [f"{prefix}drone/**", f"{prefix}sensor/**"]},
        {"id": "no-commands", "permission": "deny", "flows": ["ingress"], "messages": ["query"],
         "key_exprs": [f"{prefix}drone/*/cmd", f"{prefix}drone/*/bundle"]},
        {"id": "catch-up", "permission": "allow", "flows": ["ingress"], "messages": ["query"],
         "key_exprs": [f"{prefix}ground/**"]},
    ]
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    identities = _identities(pki_dir)
    if "ground" not in identities.values():  # a drone's directory need not hold the ground's certificate
        identities["ground"] = "ground"
    for cn, role in identities.items():
        subjects.append({"id": cn, "cert_common_names": [cn]})
        if role == "ground":
            policies.append({"rules": ["all"], "subjects": [cn]})
        elif role == "relay":
            policies.append({"rules": ["forward", "probes", "learn", "ground-state"], "subjects": [cn]})
        elif role == "operator":
            policies.append({"rules": ["read", "read-out"], "subjects": [cn]})
        elif role == "observer":
            rules.append({"id": f"observer-{cn}", "permission": "allow", "flows": ["ingress"],
                          "messages": ["put", "delete", "liveliness_token", "declare_queryable", "reply"],
                          "key_exprs": [f"{prefix}ground/{cn}", f"{prefix}ground/{cn}/**"]})
            policies.append({"rules": ["read", "read-out", "learn", "catch-up", f"observer-{cn}"], "subjects": [cn]})
        elif role == "sensor":  # a field sensor (SPEC §2): its readings and its token, nothing else
            rules.append({"id": f"field-{cn}", "permission": "allow", "flows": ["ingress"],
                          "messages": ["put", "liveliness_token"], "key_exprs": [f"{prefix}sensor/{cn}/**"]})
            policies.append({"rules": [f"field-{cn}", "learn", "ground-state"], "subjects": [cn]})
        else:
            rules.append({"id": f"own-{cn}", "permission": "allow", "flows": BOTH, "messages": ALL_MESSAGES,
                          "key_exprs": [f"{prefix}drone/{cn}/**", f"{prefix}drone/{cn}"]})
            policies.append({"rules": [f"own-{cn}", "probes", "learn", "ground-state", "no-commands"], "subjects": [cn]})
    if bridges is not None and bridges[1]:
        own, zids = bridges
        subjects.append({"id": f"bridges-of-{own}", "cert_common_names": [own], "zids": sorted(zids)})
        policies.append({"rules": ["all"], "subjects": [f"bridges-of-{own}"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def mesh_security(security: Security, name: str, endpoints: list[str], *, router: bool,
                  namespace: str = "", bridge_zids: frozenset[str] = frozenset()) -> dict[str, Any]:
    """The Zenoh settings (for `ZenohBus.open(extra=…)`) of a node called `name`."""
    if not security.tls:
        return {}
    assert security.pki_dir is not None
    pki = Path(security.pki_dir).expanduser()
    name = security.name or name
    files = [pki / "ca.pem", pki / f"{name}.pem", pki / f"{name}.key"]
    missing = [str(f) for f in files if not f.exists()]
    if missing:
        raise ConfigError(f"security.tls: missing {', '.join(missing)} (`fleet pki issue {pki} {name} --role …`)")
    plain = [e for e in endpoints if not e.startswith("tls/")]
    if plain:
        raise ConfigError(f"security.tls: every endpoint must be tls/…, not {', '.join(plain)}")
    extra: dict[str, Any] = {
        "transport/link/tls/root_ca_certificate": str(files[0]),
        "transport/link/tls/listen_certificate": str(files[1]),
        "transport/link/tls/listen_private_key": str(files[2]),
        "transport/link/tls/connect_certificate": str(files[1]),
        "transport/link/tls/connect_private_key": str(files[2]),
        "transport/link/tls/enable_mtls": True,
    }
    if router:
        extra["access_control"] = access_control(pki, namespace, (name, bridge_zids))
        extra["transport/link/tls/verify_name_on_connect"] = security.verify_names
    return extra
