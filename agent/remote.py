"""Talking to an agent from elsewhere on the mesh: send a command, read the reply.

Used by the ground, the demo and tests. A command goes to `drone/<id>/cmd` as a
query; the reply says whether the agent took it. Completion arrives as status.
"""

from __future__ import annotations

import time
from typing import Any

import msgspec

from dronefleet.bus.port import Bus
from dronefleet.schemas.codec import encode
from dronefleet.schemas.commands import CommandReply, new_command_id
from dronefleet.schemas.keys import Keys

DEFAULT_KEYS = Keys()

_reply_decoder = msgspec.json.Decoder(CommandReply)


async def send_command(
    bus: Bus, drone_id: str, cmd: str, *, keys: Keys = DEFAULT_KEYS, timeout_s: float = 3.0, **fields: Any
) -> CommandReply:
    """Send one command (fields as in SPEC §2); raises bus Unreachable/QueryTimeout."""
    body = {
        "drone_id": drone_id,
        "command_id": fields.pop("command_id", None) or new_command_id(),
        "timestamp": time.time_ns() // 1_000_000,
        "cmd": cmd,
        **fields,
    }
    raw = await bus.query(keys.cmd(drone_id), encode(body), timeout_s=timeout_s)
    return _reply_decoder.decode(raw)
