"""The one registry shape (secuav_common/registry.py): built-ins in order, then plugins through the one lookup."""

from __future__ import annotations

import fractions
from typing import Any

import pytest

from secuav_common import plugins
from secuav_common.registry import Registry


def _a_class(obj: Any, where: str) -> type:
    if not isinstance(obj, type):
        raise plugins.PluginError(f"{where} is not a class")
    return obj


def test_built_ins_keep_their_order_and_a_name_is_taken_once() -> None:
    reg: Registry[type] = Registry("widget", check=_a_class)
    reg.register("b", int)
    reg.register("a", float)
    assert reg.builtin_names() == ["b", "a"] and reg.names() == ["b", "a"]
    assert reg.lookup("a") is float and reg.lookup("c") is None
    for name in ("a", ""):
        with pytest.raises(ValueError, match="widget name"):
            reg.register(name, str)
    reg.unregister("b")
    assert reg.builtin_names() == ["a"] and reg.lookup("b") is None


def test_a_reference_is_imported_checked_and_without_a_key_never_entered() -> None:
    reg: Registry[type] = Registry("widget", plugins.ESTIMATORS, _a_class)
    assert reg.lookup("fractions:Fraction") is fractions.Fraction
    assert "fractions:Fraction" not in reg.table and reg.table == {}
    with pytest.raises(plugins.PluginError, match="fractions:gcd_missing"):
        reg.lookup("fractions:gcd_missing")
    with pytest.raises(plugins.PluginError, match="is not a class"):
        reg.lookup("fractions:__name__")


def test_with_a_key_a_reference_joins_the_table_under_its_own_name() -> None:
    reg: Registry[type] = Registry("widget", plugins.PRIMITIVES, _a_class, key=lambda cls: cls.__name__.lower())
    reg.register("int", int)
    assert reg.lookup("fractions:Fraction") is fractions.Fraction
    assert reg.table == {"int": int, "fraction": fractions.Fraction}
    assert reg.builtin_names() == ["int"] and not reg.is_builtin("fraction")
    assert reg.lookup("fraction") is fractions.Fraction  # found again by the name it gave itself


def test_the_installed_example_plugin_is_found_by_the_estimators_and_primitives_registries() -> None:
    """The example distribution (examples/plugin, installed by scripts/setup.sh) declares huber and moving_bias."""
    from attack_profiles.primitives import REGISTRY as PRIMITIVES
    from estimators.registry import REGISTRY as ESTIMATORS

    assert "huber" in ESTIMATORS.names() and "huber" not in ESTIMATORS.table
    huber = ESTIMATORS.lookup("huber")
    assert huber is not None and huber.name == "huber"
    assert ESTIMATORS.origin("huber")[0] != "secuav"
    kinds = PRIMITIVES.names()
    assert "moving_bias" in kinds and kinds.index("moving_bias") > kinds.index("bias")
    moving = PRIMITIVES.lookup("moving_bias")
    assert moving is not None and PRIMITIVES.table["moving_bias"] is moving
