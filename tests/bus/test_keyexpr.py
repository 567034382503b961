"""Key-expression intersection as Zenoh defines it."""

import pytest

from dronefleet.bus.keyexpr import intersects


@pytest.mark.parametrize(
    ("a", "b", "expected"),
    [
        ("drone/d1/telem", "drone/d1/telem", True),
        ("drone/*/telem", "drone/d1/telem", True),
        ("drone/*/telem", "drone/d1/status", False),
        ("drone/**", "drone/d1/sensor/temperature", True),
        ("drone/d1/**", "drone/d1", True),
        ("**", "anything/at/all", True),
        ("drone/*", "drone/d1/telem", False),
        ("drone/**/temperature", "drone/d1/sensor/temperature", True),
        ("fleetA/drone/*/telem", "drone/d1/telem", False),
        ("drone/d1/*", "drone/*/cmd", True),
    ],
)
def test_intersects(a: str, b: str, expected: bool) -> None:
    assert intersects(a, b) is expected
    assert intersects(b, a) is expected
