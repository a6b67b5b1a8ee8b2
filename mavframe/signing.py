"""MAVLink 2 message signing for the proxy: verify what arrives, sign what we changed or made.

Key file (``--signing-key FILE``): the 32-byte secret shared with the vehicle and
the ground station, written either as exactly 32 raw bytes, or as text holding
64 hex digits, or as text holding the standard base64 of 32 bytes (what
``base64`` prints; MAVProxy's ``signing setup`` passphrase is hashed to such a key
with SHA-256). Whitespace around text keys is ignored.

Signature (MAVLink signing spec): ``link_id (1) | timestamp (6, LE, 10 µs units
since 2015-01-01 UTC) | first 6 bytes of SHA-256(key | header | payload | CRC |
link_id | timestamp)``, appended to a v2 frame whose incompat flag 0x01 is set.

Policy, as PX4 behaves with signing enabled (``MAV_SIGN_CFG`` > 0):
- a signed frame whose signature does not match, or whose timestamp is not newer
  than the last one seen on its stream (sysid, compid, link id), is rejected:
  PX4's parser drops it, so the proxy drops it too and counts ``bad_signature``
  or ``stale_signature`` (forwarding it would only shift the rejection);
- unsigned frames are forwarded as they are; accepting them is the endpoint's
  decision (PX4 accepts a few, e.g. RADIO_STATUS, and all on USB);
- a frame the proxy modified keeps its link id and original timestamp (so the
  stream stays monotonic for the receiver) unless an earlier re-signed frame of
  the same stream already used it, then ``last + 1``;
- a frame the proxy injects is signed on the proxy's own link id with
  ``max(last + 1, now)``, a stream of its own as the spec asks of every signer.
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import hmac
import struct
import time
from collections.abc import Callable
from pathlib import Path
from typing import Final

from secuav_common.loading import InputError

__all__ = ["BAD_SIGNATURE", "STALE_SIGNATURE", "Signer", "parse_key", "timestamp_now"]

KEY_LEN: Final = 32
SIGNATURE_LEN: Final = 13
IFLAG_SIGNED: Final = 0x01
EPOCH_2015_S: Final = 1420070400  # 2015-01-01T00:00:00Z
BAD_SIGNATURE: Final = "bad_signature"
STALE_SIGNATURE: Final = "stale_signature"
DEFAULT_LINK_ID: Final = 0xFE  # the proxy's own link id for injected frames

_TS = struct.Struct("<Q")


def timestamp_now(wall_s: float) -> int:
    """MAVLink signing timestamp of a UNIX time: 10 µs units since 2015-01-01."""
    return int((wall_s - EPOCH_2015_S) * 100_000)


def parse_key(data: bytes, source: str = "<key>") -> bytes:
    """The 32-byte key in ``data`` (raw, hex text or base64 text); ``InputError`` naming ``source`` otherwise."""
    if len(data) == KEY_LEN:
        return bytes(data)
    text = data.strip()
    if len(text) == 2 * KEY_LEN:
        try:
            return binascii.unhexlify(text)
        except binascii.Error:
            pass
    try:
        key = base64.b64decode(text, validate=True)
    except (binascii.Error, ValueError):
        key = b""
    if len(key) == KEY_LEN:
        return key
    raise InputError(source, "key", f"{len(data)} bytes", "need 32 raw bytes, 64 hex digits or base64 of 32 bytes")


class Signer:
    """Verifies and makes signatures with one link key; keeps per-stream timestamps."""

    def __init__(
        self,
        key: bytes,
        link_id: int = DEFAULT_LINK_ID,
        *,
        wall_clock: Callable[[], float] = time.time,
    ) -> None:
        if len(key) != KEY_LEN:
            raise ValueError(f"signing key must be {KEY_LEN} bytes, got {len(key)}")
        if not 0 <= link_id <= 255:
            raise ValueError(f"link id must be 0..255, got {link_id}")
        self.key = bytes(key)
        self.link_id = link_id
        self._wall_clock = wall_clock
        self._seen: dict[tuple[int, int, int], int] = {}  # stream -> last timestamp accepted
        self._sent: dict[tuple[int, int, int], int] = {}  # stream -> last timestamp we signed

    def for_link(self) -> Signer:
        """The same key with replay state of its own, for one link's pipeline.

        Every link must judge freshness alone: a signed frame with no target (a
        GCS HEARTBEAT on a ground port several vehicles share) reaches each of
        them, and with one table the second and third vehicle saw it as a replay.
        """
        return Signer(self.key, self.link_id, wall_clock=self._wall_clock)

    @classmethod
    def from_file(cls, path: str | Path, link_id: int = DEFAULT_LINK_ID) -> Signer:
        from secuav_common.broker import read_secret

        p = Path(path)
        return cls(parse_key(read_secret(p, "key"), str(p)), link_id)

    def _digest(self, body: bytes | bytearray | memoryview, link_id: int, ts: int) -> bytes:
        h = hashlib.sha256(self.key)
        h.update(body)
        h.update(bytes((link_id,)))
        h.update(_TS.pack(ts)[:6])
        return h.digest()[:6]

    def verify(self, frame: bytes) -> str | None:
        """``None`` if the signed v2 ``frame`` is authentic and fresh, else the reason it is rejected."""
        if len(frame) < 10 + 2 + SIGNATURE_LEN or not frame[2] & IFLAG_SIGNED:
            return BAD_SIGNATURE
        body_end = len(frame) - SIGNATURE_LEN
        link_id = frame[body_end]
        ts = _TS.unpack(frame[body_end + 1 : body_end + 7] + b"\0\0")[0]
        expected = self._digest(memoryview(frame)[:body_end], link_id, ts)
        if not hmac.compare_digest(expected, frame[body_end + 7 :]):
            return BAD_SIGNATURE
        stream = (frame[5], frame[6], link_id)
        last = self._seen.get(stream)
        if last is not None and ts <= last:
            return STALE_SIGNATURE
        self._seen[stream] = ts
        return None

    def _sign(self, body: bytes, link_id: int, ts: int, sysid: int, compid: int) -> bytes:
        self._sent[(sysid, compid, link_id)] = ts
        return body + bytes((link_id,)) + _TS.pack(ts)[:6] + self._digest(body, link_id, ts)

    def resign(self, body: bytes, original: bytes) -> bytes:
        """Sign the re-packed ``body`` (header with flag 0x01 + payload + CRC) like ``original`` was."""
        sig_at = len(original) - SIGNATURE_LEN
        link_id = original[sig_at]
        orig_ts = _TS.unpack(original[sig_at + 1 : sig_at + 7] + b"\0\0")[0]
        sysid, compid = body[5], body[6]
        last = self._sent.get((sysid, compid, link_id), -1)
        return self._sign(body, link_id, max(orig_ts, last + 1), sysid, compid)

    def sign_new(self, body: bytes) -> bytes:
        """Sign a frame the proxy made, on its own link id, ``max(last + 1, now)``."""
        sysid, compid = body[5], body[6]
        last = self._sent.get((sysid, compid, self.link_id), -1)
        ts = max(last + 1, timestamp_now(self._wall_clock()))
        return self._sign(body, self.link_id, ts, sysid, compid)
