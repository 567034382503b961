"""Encoding and the typed decoder of each key family.

Payloads are compact JSON so `z_sub` and `fleet sub` show them readably. Decoders
are built once (msgspec validates while it parses); a bad payload becomes an
InvalidMessage naming the field, never a bare msgspec exception.
"""

from __future__ import annotations

from typing import Any

import msgspec

from dronefleet.schemas.about import About
from dronefleet.schemas.bundles import BundleRecord, BundleStatus
from dronefleet.schemas.commands import decode_command
from dronefleet.schemas.errors import InvalidMessage
from dronefleet.schemas.status import CommandStatus, Status, SystemStatus
from dronefleet.schemas.telemetry import LinkQuality, SensorReading, Telemetry

_encoder = msgspec.json.Encoder()
encode = _encoder.encode


class _StatusShape(msgspec.Struct):
    command: str | None = None
    component: str | None = None
    bundle_id: str | None = None


_decoders: dict[type, msgspec.json.Decoder] = {
    t: msgspec.json.Decoder(t)
    for t in (Telemetry, SensorReading, About, LinkQuality, CommandStatus, SystemStatus, BundleStatus, BundleRecord, _StatusShape)
}


def _decode(payload: bytes, kind: type) -> Any:
    try:
        return _decoders[kind].decode(payload)
    except msgspec.ValidationError as exc:
        raise InvalidMessage(f"{kind.__name__}: {exc}") from None
    except msgspec.DecodeError as exc:
        raise InvalidMessage(f"{kind.__name__}: malformed JSON: {exc}") from None


def decode_telemetry(payload: bytes) -> Telemetry:
    return _decode(payload, Telemetry)


def decode_sensor(payload: bytes) -> SensorReading:
    return _decode(payload, SensorReading)


def decode_about(payload: bytes) -> About:
    return _decode(payload, About)


def decode_link(payload: bytes) -> LinkQuality:
    return _decode(payload, LinkQuality)


def decode_status(payload: bytes) -> Status | BundleStatus:
    """BundleStatus when the payload has `bundle_id`, CommandStatus when it has
    `command`, SystemStatus when it has `component`."""
    shape = _decode(payload, _StatusShape)
    if shape.bundle_id is not None:
        return _decode(payload, BundleStatus)
    if shape.command is not None:
        return _decode(payload, CommandStatus)
    if shape.component is not None:
        return _decode(payload, SystemStatus)
    raise InvalidMessage("status has neither `command` nor `component`", field="$.command")


def decode_bundle_record(payload: bytes) -> BundleRecord:
    return _decode(payload, BundleRecord)


__all__ = ["decode_about", "decode_bundle_record", "decode_command", "decode_link", "decode_sensor", "decode_status", "decode_telemetry", "encode"]
