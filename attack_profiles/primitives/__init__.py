"""The attack primitives, one module each, all of the shape of :class:`~.base.Primitive`.

Adding a primitive means adding a module with its rule model and its class and
listing the class here; the profile schema and the engine pick it up from
:data:`PRIMITIVES`.
"""

from __future__ import annotations

from attack_profiles.primitives.base import Context, Primitive, Sample
from attack_profiles.primitives.bias import Bias
from attack_profiles.primitives.coordinated_spoof import CoordinatedSpoof
from attack_profiles.primitives.delay import Delay
from attack_profiles.primitives.drop import Drop
from attack_profiles.primitives.freeze import Freeze
from attack_profiles.primitives.garbage import Garbage
from attack_profiles.primitives.intermittent import Intermittent
from attack_profiles.primitives.noise import Noise
from attack_profiles.primitives.ramp import Ramp
from attack_profiles.primitives.replay import Replay
from attack_profiles.primitives.scale import Scale
from attack_profiles.primitives.set import Set
from attack_profiles.primitives.sinusoid import Sinusoid

PRIMITIVES: dict[str, type[Primitive]] = {
    cls.kind: cls
    for cls in (
        Bias,
        Ramp,
        Sinusoid,
        Noise,
        Scale,
        Set,
        Freeze,
        Replay,
        Delay,
        Drop,
        Intermittent,
        Garbage,
        CoordinatedSpoof,
    )
}

__all__ = ["PRIMITIVES", "Context", "Primitive", "Sample"]
