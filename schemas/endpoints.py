"""Zenoh endpoints and HOST:PORT pairs, checked before anything opens a socket, so a
typo is named at start ("--connect tcp/10.0.0.1:74470: port out of range") instead of
surfacing later as a library error."""

from __future__ import annotations

import re

from dronefleet.schemas.errors import ConfigError

# Zenoh's link protocols (zenoh 1.10): `<protocol>/<address>[?<metadata>][#<config>]`.
AGENT_PORT = 7448  # an agent's own router: on-board programs and neighbours connect here
IP_PROTOCOLS = frozenset({"tcp", "udp", "tls", "quic", "ws"})
OTHER_PROTOCOLS = frozenset({"unixsock-stream", "unixpipe", "serial", "vsock"})
_ENDPOINT = re.compile(r"^(?P<proto>[a-z][a-z0-9-]*)/(?P<address>[^?#]+)(?:\?[^#]*)?(?:#.*)?$")


def check_endpoint(endpoint: str) -> str:
    """`endpoint` unchanged if Zenoh can use it, else ConfigError naming what is wrong."""
    m = _ENDPOINT.match(endpoint)
    if m is None:
        raise ConfigError(f"{endpoint!r} is not a Zenoh endpoint: expected PROTOCOL/ADDRESS, e.g. tcp/192.168.1.10:7447")
    proto, address = m.group("proto"), m.group("address")
    if proto in OTHER_PROTOCOLS:
        return endpoint
    if proto not in IP_PROTOCOLS:
        known = ", ".join(sorted(IP_PROTOCOLS | OTHER_PROTOCOLS))
        raise ConfigError(f"{endpoint!r}: unknown protocol {proto!r} (known: {known})")
    split_host_port(address, what=endpoint)
    return endpoint


def plain_endpoint(endpoint: str) -> str:
    """`PROTOCOL/ADDRESS` without its `?metadata` and `#config` parts."""
    m = _ENDPOINT.match(endpoint)
    return f"{m.group('proto')}/{m.group('address')}" if m else endpoint


def ip_endpoint(endpoint: str) -> tuple[str, str, int] | None:
    """(protocol, host, port) of an IP endpoint (IPv6 hosts without brackets); None for
    any other endpoint, or one that does not parse."""
    m = _ENDPOINT.match(endpoint)
    if m is None or m.group("proto") not in IP_PROTOCOLS:
        return None
    try:
        host, port = split_host_port(m.group("address"))
    except ConfigError:
        return None
    return m.group("proto"), host, port


def split_host_port(text: str, *, what: str | None = None) -> tuple[str, int]:
    """`HOST:PORT` (IPv6 as `[::1]:PORT`) into its parts; ConfigError names `what`."""
    where = what or text
    host, sep, port = text.rpartition(":")
    if not sep or not host:
        raise ConfigError(f"{where!r}: expected HOST:PORT")
    if not port.isdigit():
        raise ConfigError(f"{where!r}: port {port!r} is not a number")
    if not 0 <= int(port) <= 65535:
        raise ConfigError(f"{where!r}: port {port} out of range 0-65535")
    return host.removeprefix("[").removesuffix("]"), int(port)


def check_endpoints(**lists: list[str]) -> None:
    """For a config Struct's `__post_init__`: ValueError (which msgspec reports with
    the file's name) naming the key and the endpoint at fault."""
    for key, endpoints in lists.items():
        for endpoint in endpoints:
            try:
                check_endpoint(endpoint)
            except ConfigError as exc:
                raise ValueError(f"{key}: {exc}") from None
