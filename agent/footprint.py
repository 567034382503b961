"""What the agent's process keeps resident: an agent at rest stays within 50 MiB (ADR 0018).

A companion computer shares a few hundred MiB among the autopilot link, a camera and
the user's own programs. Most of the agent's resident memory is its libraries' code
(Zenoh, libmavsdk, libpython); two things on top of them are not needed and are shed:

- **OpenSSL.** asyncio imports `ssl` and hashlib/hmac import `_hashlib` whenever they
  can; either maps and initialises libcrypto (4.6 MiB resident). The agent speaks TLS
  only through Zenoh (rustls) and signs only through `cryptography` (its own OpenSSL);
  its digests (blake2b, sha1) and `hmac.compare_digest` have built-in implementations.
  So before asyncio loads, both modules are marked absent: the standard library's own
  fallbacks take over, as on a Python built without OpenSSL.
- **Freed heap.** Start-up (imports, MAVSDK's discovery, the first sessions) frees
  memory that glibc keeps mapped; `malloc_trim` hands it back (about 2 MiB), and one
  malloc arena serves the process's few Python threads (glibc otherwise opens one per
  thread that allocates; 0.3–0.6 MiB).
"""

from __future__ import annotations

import ctypes
import functools
import platform
import sys

OPENSSL_MODULES = ("ssl", "_hashlib")
HEAP_TRIM_FIRST_S = 5.0  # after the agent starts serving: start-up's garbage is freed by then
HEAP_TRIM_EVERY_S = 60.0  # a flight's buffers, freed on landing, go back too
_M_ARENA_MAX = -8  # glibc malloc.h


def keep_openssl_out() -> None:
    """Mark `ssl` and `_hashlib` absent for this process. Call before asyncio is imported
    (this module imports neither); a module already loaded stays loaded."""
    for name in OPENSSL_MODULES:
        sys.modules.setdefault(name, None)  # type: ignore[arg-type]  # None: "not importable" (import system)


@functools.cache  # platform.libc_ver reads the interpreter's binary: once, not every minute
def _libc() -> ctypes.CDLL | None:
    """glibc, or None elsewhere (musl, macOS): the calls below are glibc's."""
    if platform.libc_ver()[0] != "glibc":
        return None
    return ctypes.CDLL(None)


def one_malloc_arena() -> None:
    """One malloc arena for the whole process. Call before threads start."""
    libc = _libc()
    if libc is not None:
        libc.mallopt(_M_ARENA_MAX, 1)


def release_freed_heap() -> None:
    """Return the heap's free pages to the system (glibc `malloc_trim`)."""
    libc = _libc()
    if libc is not None:
        libc.malloc_trim(0)
