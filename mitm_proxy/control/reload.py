"""Reload the ``--profile`` file when it changes on disk (the way mitmproxy reloads a script).

A researcher edits the profile in an editor while the vehicle flies; on save
the proxy picks it up within ``interval_s``, under the same rules as an MQTT
``attack/set``: the new profile goes through :meth:`AttackSwitch.offer` (whole,
between two frames), and a bad edit keeps the previous profile and puts the
one-line error in the switch's state (and so on ``secuav/v<sysid>/attack/state``:
the control plane publishes every state change).

Which vehicles get it: if every rule names a ``target.sysid``, the vehicles so
named; if any rule names none (or there are no rules), every vehicle. A
vehicle that this file fed before and that the edit no longer names is
cleared, unless something else (MQTT) has replaced the file's profile there
since. A sysid named with no such link is logged.

A change is noticed by the file's inode, size and mtime, then confirmed by its
content hash, so touching the file or saving it unchanged re-offers nothing,
and an editor's write-to-temp-and-rename is seen like an in-place write. On a
file system with coarse timestamps a same-size edit within one tick would look
unchanged, so every few polls the file is read and hashed regardless.
"""

from __future__ import annotations

import asyncio
import hashlib
import logging
from collections.abc import Callable, Mapping
from pathlib import Path
from types import TracebackType

from attack_profiles.profile import Profile, parse_profile
from mitm_proxy.control.attack import AttackSwitch
from secuav_common.controlplane.payloads import AttackState
from secuav_common.loading import InputError, parse_document

log = logging.getLogger(__name__)

_Signature = tuple[int, int, int]  # inode, size, mtime in ns
REHASH_EVERY = 4  # polls; at the default 0.5 s a same-size, same-mtime edit is seen within 2 s


class ProfileWatcher:
    """``async with ProfileWatcher(path, slots) as w: await w.run()``; :meth:`poll` does one check.

    The file as it is when the watcher is made counts as already applied (the
    proxy offered it at start); call :meth:`apply_now` to offer it anyway.
    """

    def __init__(
        self,
        path: str | Path,
        slots: Mapping[int, AttackSwitch],
        interval_s: float = 0.5,
        *,
        on_state: Callable[[AttackState], None] | None = None,
    ) -> None:
        self.path = Path(path)
        self.slots = slots
        self.interval_s = interval_s
        self.on_state = on_state
        self.request_id = f"file:{self.path}"
        self.reloads = 0  # accepted edits
        self.rejects = 0  # edits that failed and kept the old profile
        self._signature = self._stat()
        raw = self._read()
        self._digest = hashlib.sha256(raw).digest() if raw is not None else None
        self._installed: str | None = None  # content hash of the profile this file last installed
        self._fed: set[int] = set()  # vehicles this file's profile went to
        if raw is not None:
            try:
                profile = self._parse(raw)
            except InputError:
                pass
            else:
                self._installed = profile.content_hash()
                self._fed = {s for s, slot in slots.items() if slot.state.hash == self._installed}
        self._missing_logged = False
        self._failure_logged = False
        self._polls = 0

    async def __aenter__(self) -> ProfileWatcher:
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        return None

    async def run(self) -> None:
        """Check every ``interval_s`` until cancelled; an unexpected error is logged once and the loop goes on."""
        while True:
            await asyncio.sleep(self.interval_s)
            try:
                self.poll()
                self._failure_logged = False
            except Exception:
                if not self._failure_logged:
                    log.exception("reload.failed", extra={"path": str(self.path)})
                self._failure_logged = True

    # -- one check ------------------------------------------------------------------------------------

    def poll(self) -> list[AttackState]:
        """Reload if the file changed since the last look; the states it produced (empty: nothing to do)."""
        signature = self._stat()
        if signature is None:
            if not self._missing_logged:
                log.warning("reload.missing", extra={"path": str(self.path), "kept": self._installed is not None})
            self._missing_logged = True
            self._signature = None
            return []
        self._missing_logged = False
        self._polls += 1
        if signature == self._signature and self._polls % REHASH_EVERY:
            return []  # the fast path; every REHASH_EVERY-th poll reads anyway (see the module docstring)
        raw = self._read()
        if raw is None:
            return []  # vanished between stat and read: the next poll says so
        self._signature = signature
        digest = hashlib.sha256(raw).digest()
        if digest == self._digest:
            return []
        self._digest = digest
        return self._offer(raw)

    def apply_now(self) -> list[AttackState]:
        """Read and offer the file whatever its state; raises nothing, reports like a reload."""
        raw = self._read()
        if raw is None:
            return self._reject(f"{self.path}: cannot read the profile file")
        self._signature, self._digest = self._stat(), hashlib.sha256(raw).digest()
        return self._offer(raw)

    # -- internals ------------------------------------------------------------------------------------

    def _stat(self) -> _Signature | None:
        try:
            st = self.path.stat()
        except OSError:
            return None
        return st.st_ino, st.st_size, st.st_mtime_ns

    def _read(self) -> bytes | None:
        try:
            return self.path.read_bytes()
        except OSError:
            return None

    def _parse(self, raw: bytes) -> Profile:
        # What load_profile does, on the bytes we hashed, so the hash and the profile are the same edit.
        source = str(self.path)
        return parse_profile(parse_document(raw, source), source)

    def targets(self, profile: Profile) -> set[int]:
        """The vehicles a profile goes to (see the module docstring)."""
        named = {rule.target.sysid for rule in profile.rules}
        if not profile.rules or None in named:
            return set(self.slots)
        missing = sorted(s for s in named if s is not None and s not in self.slots)
        if missing:
            log.warning("reload.no_such_vehicle", extra={"path": str(self.path), "sysids": missing})
        return {s for s in named if s in self.slots}

    def _offer(self, raw: bytes) -> list[AttackState]:
        try:
            profile = self._parse(raw)
        except InputError as exc:
            return self._reject(str(exc))
        targets = self.targets(profile)
        states: list[AttackState] = []
        accepted: set[int] = set()
        for sysid in sorted(targets):
            state = self.slots[sysid].offer(profile, self.request_id)
            states.append(state)
            if state.ok:
                accepted.add(sysid)
            else:
                log.warning("reload.rejected", extra={"path": str(self.path), "sysid": sysid, "error": state.error})
        if targets and not accepted:  # every vehicle refused it (e.g. a sensor its scenario lacks): no change
            self.rejects += 1
            self._notify(states)
            return states
        for sysid in sorted(self._fed - targets):
            if self.slots[sysid].state.hash == self._installed:  # still the file's profile: take it away
                states.append(self.slots[sysid].offer(None, self.request_id))
        self.reloads += 1
        self._installed = profile.content_hash()
        self._fed = accepted
        log.info(
            "reload.applied",
            extra={"path": str(self.path), "profile": profile.name, "hash": self._installed[:12],
                   "sysids": sorted(accepted)},
        )  # fmt: skip
        self._notify(states)
        return states

    def _reject(self, error: str) -> list[AttackState]:
        self.rejects += 1
        log.warning("reload.rejected", extra={"path": str(self.path), "error": error})
        ours = [s for s in sorted(self._fed) if self.slots[s].state.hash == self._installed]
        states = [self.slots[s].reject(error, self.request_id) for s in (ours or sorted(self.slots))]
        self._notify(states)
        return states

    def _notify(self, states: list[AttackState]) -> None:
        if self.on_state is not None:
            for state in states:
                self.on_state(state)
