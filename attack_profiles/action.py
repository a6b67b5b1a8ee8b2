"""What the engine tells its caller to do with one message.

This is the contract between the attack engine and its two users: the proxy's
attack stage (live MAVLink) and the offline evaluation. Field values are in
*wire units* (what pymavlink decodes: cm, 1e7 deg, mm, ...); the engine does the
physical-unit conversion itself.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True, slots=True)
class Action:
    """Outcome for one message. The default instance means "forward unchanged".

    - ``drop``: do not forward the message (``fields`` and ``delay_s`` are then ignored);
    - ``fields``: changed fields only, wire units; ``None`` means unchanged;
    - ``delay_s``: hold the (possibly changed) message back this long;
    - ``rules``: indices of the rules that acted, for the recording index;
    - ``clamped``: names of fields whose attacked value was clamped to the wire range.
    """

    drop: bool = False
    fields: dict[str, Any] | None = None
    delay_s: float = 0.0
    rules: tuple[int, ...] = ()
    clamped: tuple[str, ...] = field(default=())

    @property
    def untouched(self) -> bool:
        return not (self.drop or self.fields or self.delay_s > 0.0)


FORWARD = Action()
