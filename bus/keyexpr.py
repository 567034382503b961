"""Key-expression intersection (`*` = one chunk, `**` = any number of chunks).

Used by the in-memory bus to route like Zenoh does; the Zenoh adapter lets Zenoh
itself do the matching.
"""

from __future__ import annotations

from functools import lru_cache


def strip_parameters(selector: str) -> str:
    return selector.split("?", 1)[0]


@lru_cache(maxsize=4096)
def intersects(a: str, b: str) -> bool:
    return _match(tuple(a.split("/")), tuple(b.split("/")))


def _match(a: tuple[str, ...], b: tuple[str, ...]) -> bool:
    if not a and not b:
        return True
    if a and a[0] == "**":
        return _match(a[1:], b) or (bool(b) and _match(a, b[1:]))
    if b and b[0] == "**":
        return _match(a, b[1:]) or (bool(a) and _match(a[1:], b))
    if not a or not b:
        return False
    if a[0] == "*" or b[0] == "*" or a[0] == b[0]:
        return _match(a[1:], b[1:])
    return False
