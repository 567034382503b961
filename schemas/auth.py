"""End-to-end command authority (SPEC §9): the ground signs every command and bundle
with its Ed25519 key; an agent that knows the ground's public key refuses what is
unsigned, forged, expired or replayed, whatever path it came by.

The signature covers the message's canonical JSON without its `auth` (msgspec encodes
a Struct's fields in one order, so both ends derive the same bytes), the ground's id
and the signing time: `<canonical>|<ground>|<ts>`. The command or bundle id inside
makes each signature single-use: an agent remembers the ids it took for the window.
"""

from __future__ import annotations

import base64
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import msgspec

from dronefleet.schemas.errors import ConfigError

if TYPE_CHECKING:
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

REASON = "unauthenticated"
SIGNING_KEY, SIGNING_PUB = "signing.key", "signing.pub"  # in a PKI directory (`fleet pki init`)


class Auth(msgspec.Struct, frozen=True, kw_only=True):
    ground: str  # who signed
    ts: int  # ms since the epoch, when it was signed
    sig: str  # base64 Ed25519 signature


T = TypeVar("T", bound=msgspec.Struct)


def _signed_bytes(message: msgspec.Struct, ground: str, ts: int) -> bytes:
    unsigned = msgspec.structs.replace(message, auth=None)
    return msgspec.json.encode(unsigned) + f"|{ground}|{ts}".encode()


def load_private_key(path: Path) -> Ed25519PrivateKey:
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
    from cryptography.hazmat.primitives.serialization import load_pem_private_key

    key = load_pem_private_key(path.read_bytes(), password=None)
    if not isinstance(key, Ed25519PrivateKey):
        raise ValueError(f"{path} is not an Ed25519 private key")
    return key


def load_public_key(path: Path) -> Ed25519PublicKey:
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey
    from cryptography.hazmat.primitives.serialization import load_pem_public_key

    key = load_pem_public_key(path.read_bytes())
    if not isinstance(key, Ed25519PublicKey):
        raise ValueError(f"{path} is not an Ed25519 public key")
    return key


class Signer:
    """The ground's side: `sign(command)` returns it with `auth` set."""

    def __init__(self, key: Ed25519PrivateKey, ground: str) -> None:
        self.key = key
        self.ground = ground

    def sign(self, message: T, ts: int) -> T:
        sig = self.key.sign(_signed_bytes(message, self.ground, ts))
        auth = Auth(ground=self.ground, ts=ts, sig=base64.b64encode(sig).decode())
        return msgspec.structs.replace(message, auth=auth)


class Verifier:
    """The agent's side: `refusal(message, id, now_ms)` is None for a command the
    ground signed within the window and that was not seen before, else the reason."""

    def __init__(self, key: Ed25519PublicKey, window_s: float = 30.0) -> None:
        self.key = key
        self.window_ms = int(window_s * 1000)
        self._seen: dict[str, int] = {}  # message id → signing time, oldest first, for the window

    def refusal(self, message: Any, message_id: str, now_ms: int) -> str | None:
        from cryptography.exceptions import InvalidSignature

        auth: Auth | None = message.auth
        if auth is None:
            return f"{REASON}: not signed by the ground"
        try:
            self.key.verify(base64.b64decode(auth.sig, validate=True), _signed_bytes(message, auth.ground, auth.ts))
        except (InvalidSignature, ValueError):
            return f"{REASON}: the signature does not verify with the ground's key"
        if abs(now_ms - auth.ts) > self.window_ms:
            return f"{REASON}: signed {(now_ms - auth.ts) / 1000:+.1f} s from now, outside the {self.window_ms / 1000:g} s window"
        while self._seen:  # forget what the window refuses anyway (taken in about signing order)
            oldest, ts = next(iter(self._seen.items()))
            if now_ms - ts <= 2 * self.window_ms:
                break
            del self._seen[oldest]
        if not message_id:
            return f"{REASON}: a signed message must carry its id"
        if message_id in self._seen:
            return f"{REASON}: {message_id} was already taken (a replay)"
        self._seen[message_id] = auth.ts
        return None


def signer_of(pki_dir: str | None, ground: str = "ground") -> Signer | None:
    """The ground's Signer from a PKI directory (None without one). A directory without
    the signing key is a configuration error, said at start."""
    if pki_dir is None:
        return None
    path = Path(pki_dir).expanduser() / SIGNING_KEY
    if not path.exists():
        raise ConfigError(f"security.pki_dir: no {path} (made by `fleet pki init {pki_dir}`)")
    return Signer(load_private_key(path), ground)


def verifier_of(pki_dir: str | None, ground_key: str | None, window_s: float) -> Verifier | None:
    """An agent's Verifier: from `ground_key`, else `<pki_dir>/signing.pub`; None with neither."""
    if ground_key is None and pki_dir is None:
        return None
    path = Path(ground_key).expanduser() if ground_key else Path(pki_dir or ".").expanduser() / SIGNING_PUB
    if not path.exists():
        raise ConfigError(f"security: no ground public key at {path} (copy it from the ground's `fleet pki init` directory)")
    return Verifier(load_public_key(path), window_s)
