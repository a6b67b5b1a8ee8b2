"""Seeded noise sources, so the same scenario seed gives the same run.

Every sensor and error process draws from its own stream, derived from
``(scenario seed, sysid, stream name)``; adding a sensor therefore does not
change the noise any other sensor sees. Python's ``random.Random`` is used
rather than numpy because draws are one scalar at a time in the step loop,
where numpy's call overhead would cost more than the draw.
"""

from __future__ import annotations

import hashlib
import math
import random


def stream(seed: int, sysid: int, name: str) -> random.Random:
    """An independent, reproducible generator for one noise source."""
    digest = hashlib.sha256(f"{seed}/{sysid}/{name}".encode()).digest()
    return random.Random(int.from_bytes(digest[:8], "little"))


class GaussMarkov:
    """First-order Gauss-Markov process: slowly wandering error with a fixed spread.

    ``x[k+1] = phi x[k] + sqrt(1 - phi^2) std w[k]`` with ``phi = exp(-dt/tau)``,
    so its stationary standard deviation is ``std`` and its correlation time
    ``tau_s`` (GNSS position errors look like this over tens of seconds).
    """

    def __init__(self, rng: random.Random, std: float, tau_s: float) -> None:
        self._rng = rng
        self.std = std
        self.tau_s = tau_s
        self.value = rng.gauss(0.0, std) if std > 0 else 0.0

    def step(self, dt_s: float) -> float:
        if self.std > 0:
            phi = math.exp(-dt_s / self.tau_s)
            self.value = phi * self.value + math.sqrt(1 - phi * phi) * self.std * self._rng.gauss(0.0, 1.0)
        return self.value
