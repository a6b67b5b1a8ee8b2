"""The attack primitives, one module each, all of the shape of :class:`~.base.Primitive`.

Adding a built-in primitive means adding a module with its rule model and its
class and listing the class here. Another distribution adds one without touching
this tree: a ``secuav.primitives`` entry point named by the primitive's ``kind``
(docs/plugins.md), or ``kind: package.module:Class`` in a profile. Either way
:func:`primitive` finds it, enters it in :data:`PRIMITIVES`, and the profile
model, its schema and the engine take it from there.
"""

from __future__ import annotations

from attack_profiles.primitives.base import Context, Primitive, Sample
from attack_profiles.primitives.bias import Bias
from attack_profiles.primitives.coordinated_spoof import CoordinatedSpoof
from attack_profiles.primitives.delay import Delay
from attack_profiles.primitives.drop import Drop
from attack_profiles.primitives.duplicate import Duplicate
from attack_profiles.primitives.frame_replay import FrameReplay
from attack_profiles.primitives.freeze import Freeze
from attack_profiles.primitives.garbage import Garbage
from attack_profiles.primitives.inject import Inject
from attack_profiles.primitives.intermittent import Intermittent
from attack_profiles.primitives.mission_shift import MissionShift
from attack_profiles.primitives.noise import Noise
from attack_profiles.primitives.ramp import Ramp
from attack_profiles.primitives.replay import Replay
from attack_profiles.primitives.scale import Scale
from attack_profiles.primitives.set import Set
from attack_profiles.primitives.sinusoid import Sinusoid
from attack_profiles.rule import RuleBase
from secuav_common import plugins
from secuav_common.registry import Registry


def _checked(cls: object, where: str) -> type[Primitive]:
    if not (isinstance(cls, type) and issubclass(cls, Primitive)):
        raise plugins.PluginError(f"{where}: {cls!r} is not an attack_profiles Primitive subclass")
    kind = getattr(cls, "kind", None)
    rule_model = getattr(cls, "rule_model", None)
    if not isinstance(kind, str) or not (isinstance(rule_model, type) and issubclass(rule_model, RuleBase)):
        raise plugins.PluginError(f"{where}: {cls.__name__} needs a str kind and a RuleBase rule_model")
    if rule_model.model_fields.get("kind") is None or rule_model.model_fields["kind"].default != kind:
        raise plugins.PluginError(f"{where}: {rule_model.__name__}.kind must be Literal[{kind!r}] = {kind!r}")
    taken = PRIMITIVES.get(kind)
    if taken is not None and taken is not cls:
        raise plugins.PluginError(f"{where}: kind {kind!r} is taken by {taken.__module__}.{taken.__name__}")
    return cls


# A plugin, once found, joins the table under its kind: the profile model, its schema and the engine read it.
REGISTRY: Registry[type[Primitive]] = Registry("primitive", plugins.PRIMITIVES, _checked, key=lambda cls: cls.kind,
                                               key_label="kind")  # fmt: skip
for _cls in (
    Bias, Ramp, Sinusoid, Noise, Scale, Set, Freeze, Replay, Delay, Drop, Intermittent, Garbage, CoordinatedSpoof,
    # Frame operations (attack_profiles/frame_ops.py runs them, not the value engine):
    Inject, Duplicate, FrameReplay, MissionShift,
):  # fmt: skip
    REGISTRY.register(_cls.kind, _cls)
PRIMITIVES: dict[str, type[Primitive]] = REGISTRY.table  # kind -> class; plugins are entered as they are found
BUILTIN_KINDS = frozenset(REGISTRY.builtin_names())


def primitive(kind: str) -> type[Primitive] | None:
    """The primitive of ``kind`` (built-in, plugin entry point, or ``package.module:Class``), or None.

    Imports only that one plugin; a plugin is entered in :data:`PRIMITIVES` under its kind.
    Raises ``PluginError`` for a ``module:Class`` reference that cannot be used.
    """
    return REGISTRY.lookup(kind)


def kinds() -> list[str]:
    """Every kind a profile may name: the built-ins, then the plugins' (metadata only, nothing imported)."""
    return REGISTRY.names()


def load_all() -> dict[str, type[Primitive]]:
    """Every primitive, plugins imported (a listing, a schema); those that fail are reported and left out."""
    REGISTRY.load_all()
    return dict(PRIMITIVES)


__all__ = [
    "BUILTIN_KINDS", "PRIMITIVES", "REGISTRY", "Context", "Primitive", "Sample", "kinds", "load_all", "primitive",
]  # fmt: skip
