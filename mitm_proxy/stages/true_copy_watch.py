"""Which of the active profile's true copies this vehicle really sends: warned about once seen.

:func:`attack_profiles.true_copy.findings` lists the messages that may still
carry an attacked value true (a DISTANCE_SENSOR rule leaves ArduPilot's
RANGEFINDER). Whether they are on the wire depends on the vehicle: flightsim and
PX4 never send RANGEFINDER. The watch asks the pipeline for those message ids
(the attack stage's ``message_ids``) until each has been seen once from the
vehicle, toward the ground; a finding becomes a warning when one of its
messages arrives, naming only the carriers that did. So a profile on the
bench's own simulator says nothing about RANGEFINDER, and one in front of
ArduPilot says it as soon as ArduPilot sends one. A seen message stops being
watched: the cost is one frame per message and profile.

What the vehicle was seen sending is kept across profiles (:attr:`TrueCopyWatch.sent`
is the link's, handed from one watch to the next).
"""

from __future__ import annotations

from attack_profiles.true_copy import Finding
from mavframe import codec


class TrueCopyWatch:
    """The findings of one installed profile and the messages still to be seen; see the module doc."""

    def __init__(self, found: list[Finding], sent: set[str]) -> None:
        self.findings = found
        self.sent = sent  # message names this vehicle was seen sending (shared with the slot)
        wanted = frozenset().union(*(f.messages for f in found)) - sent
        self._pending = {int(cls.id): name for name in wanted if (cls := codec.BY_NAME.get(name)) is not None}
        self.message_ids: frozenset[int] = frozenset(self._pending)
        self.warnings: list[str] = self._texts()

    def _texts(self) -> list[str]:
        return [text for f in self.findings if (text := f.text(self.sent)) is not None]

    def see(self, msgid: int) -> list[str]:
        """A frame of ``msgid`` from the vehicle, toward the ground; returns the warnings it made new."""
        name = self._pending.pop(msgid, None)
        if name is None:
            return []
        self.sent.add(name)
        self.message_ids = frozenset(self._pending)
        before = set(self.warnings)
        self.warnings = self._texts()
        return [w for w in self.warnings if w not in before]
