"""The neighbour scout (bus/scout_assist.py): what it sends and hands on, with the
transport captured. The whole path (a drone relinking through a neighbour that comes
back into range, on the emulated radio) is tests/test_field_network.py."""

from __future__ import annotations

from typing import Any

from bus.scout_assist import SCOUT_ROUTERS, SCOUTING_GROUP, NeighbourScout, is_local_address

HELLO_A = bytes((0x22, 0x09, 0xF0)) + b"A" * 16  # a Hello (id 0x02) with flags set in the header
HELLO_OWN = bytes((0x22, 0x09, 0xF0)) + b"B" * 16
OWN = ("10.231.0.3", 44989)
NEIGHBOUR = ("10.231.0.2", 51000)


class Captured:
    def __init__(self) -> None:
        self.sent: list[tuple[bytes, Any]] = []

    def sendto(self, data: bytes, addr: Any) -> None:
        self.sent.append((data, addr))

    def close(self) -> None:
        pass


def scout_with(local: set[str]) -> tuple[NeighbourScout, Captured]:
    scout = NeighbourScout(is_local=lambda ip: ip in local)
    transport = Captured()
    scout.connection_made(transport)  # type: ignore[arg-type]
    return scout, transport


def test_a_round_multicasts_one_scout_for_routers() -> None:
    scout, transport = scout_with(set())
    scout.round()
    assert transport.sent == [(SCOUT_ROUTERS, SCOUTING_GROUP)]
    assert SCOUT_ROUTERS == b"\x01\x09\x01"  # Scout, protocol 0x09, what = router


def test_a_neighbours_hello_goes_to_the_local_router_unchanged() -> None:
    scout, transport = scout_with({OWN[0]})
    scout.datagram_received(HELLO_OWN, OWN)
    scout.datagram_received(HELLO_A, NEIGHBOUR)
    assert transport.sent == [(HELLO_A, OWN)]
    assert scout.forwarded == 1


def test_hellos_heard_before_the_local_router_answered_are_kept_until_it_does() -> None:
    scout, transport = scout_with({OWN[0]})
    scout.datagram_received(HELLO_A, NEIGHBOUR)
    scout.datagram_received(HELLO_A, NEIGHBOUR)  # the same neighbour twice: handed on once
    assert transport.sent == []
    scout.datagram_received(HELLO_OWN, OWN)
    assert transport.sent == [(HELLO_A, OWN)]


def test_the_local_routers_own_hello_and_other_datagrams_are_not_handed_on() -> None:
    scout, transport = scout_with({OWN[0]})
    scout.datagram_received(HELLO_OWN, OWN)
    scout.datagram_received(SCOUT_ROUTERS, NEIGHBOUR)  # another drone's scout
    scout.datagram_received(b"", NEIGHBOUR)
    assert transport.sent == []


def test_only_addresses_of_this_host_are_local() -> None:
    assert is_local_address("127.0.0.1")
    assert not is_local_address("192.0.2.77")  # TEST-NET-1, never assigned here
