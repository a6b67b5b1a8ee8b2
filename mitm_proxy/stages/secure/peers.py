"""The latest secure position of each vehicle, shared by the secure stages of one proxy."""

from __future__ import annotations

import numpy as np


class PeerBoard:
    """Each stage posts its own estimate and reads its peers', so an inter-vehicle range can be checked
    against, and replaced by, the distance between two secure positions. All access is from the event
    loop's thread."""

    def __init__(self, max_age_s: float = 1.0) -> None:
        self.max_age_s = max_age_s
        self._pos: dict[int, tuple[np.ndarray, float]] = {}

    def post(self, sysid: int, pos_ned_m: np.ndarray, now_s: float) -> None:
        self._pos[sysid] = (pos_ned_m, now_s)

    def get(self, sysid: int, now_s: float) -> np.ndarray | None:
        entry = self._pos.get(sysid)
        if entry is None or now_s - entry[1] > self.max_age_s:
            return None
        return entry[0]
