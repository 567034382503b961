"""The `fleet` console script. A `fleet agent` process sheds what it does not use
before anything else loads (agent/footprint.py); every other command starts as is."""

from __future__ import annotations

import sys


def command_of(argv: list[str]) -> str | None:
    """The subcommand in `fleet [-v…] COMMAND …`: the group's only option is a flag."""
    return next((arg for arg in argv if not arg.startswith("-")), None)


def main() -> None:
    if command_of(sys.argv[1:]) == "agent":
        from dronefleet.agent.footprint import keep_openssl_out, one_malloc_arena

        keep_openssl_out()
        one_malloc_arena()
    from dronefleet.cli import main as cli

    cli(prog_name="fleet")
