"""Each runtime switch is cut along its three audiences, and the imports run one way.

The wire contract (``secuav_common/controlplane/switches/``), the proxy's side (``mitm_proxy/control/``) and
the command line (``mitm_proxy/tools/verbs/``) each list the built-in switches explicitly: the three lists
name the same kinds, and each side names the very contract the wire declares. Below them, the contract's
room imports nothing of the project above ``secuav_common`` and loads nothing by name, and no stage imports
the control code that drives it.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from pydantic import BaseModel, ValidationError

from mitm_proxy.control import switches as proxy_side
from mitm_proxy.tools import verbs
from secuav_common.controlplane import switches
from secuav_common.controlplane.payloads import error_text

ROOT = Path(__file__).resolve().parents[3]
ABOVE_COMMON = {"mitm_proxy", "attack_profiles", "estimators", "flightsim", "webconsole", "study", "evaluation",
                "demos", "mavframe", "scripts", "benchmarks"}  # fmt: skip


def _imports(path: Path) -> list[str]:
    """Every module ``path`` imports, at any depth of its code (a lazy import inside a function counts)."""
    names: list[str] = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.append(node.module)
    return names


def test_the_three_audiences_list_the_same_kinds() -> None:
    wire = [c.kind for c in switches.BUILT_IN]
    proxy = [cls.kind for cls in proxy_side.BUILT_IN]
    command_line = [entry.kind for entry in verbs.BUILT_IN]
    assert len(set(wire)) == len(wire) == 4
    assert sorted(wire) == sorted(proxy) == sorted(command_line)


def test_each_side_names_the_contract_the_wire_declares() -> None:
    declared = {c.kind: c for c in switches.BUILT_IN}
    for cls in proxy_side.BUILT_IN:
        assert cls.contract is declared[cls.kind] and cls.scope == declared[cls.kind].scope, cls
    for entry in verbs.BUILT_IN:
        assert entry.contract is declared[entry.kind], entry


@pytest.mark.parametrize(
    ("kind", "good", "bad", "said"),
    [
        ("attack", {"library": "wall-spoof"}, 7, "(payload): expected a profile"),
        ("attack/mode", "bypass", {"mode": "off"}, 'mode: must be "on" or "bypass" (got "off")'),
        ("secure", "off", ["secekf"], "(payload): expected null, 'off', an estimator name or an object"),
        ("routes", {"endpoints": {"ground:14550": None}}, {"endpoints": {}, "x": 1}, "endpoints: expected"),
    ],
)
def test_every_built_in_switch_has_a_request_model_that_names_what_is_wrong(
    kind: str, good: object, bad: object, said: str
) -> None:
    contract = next(c for c in switches.BUILT_IN if c.kind == kind)
    assert issubclass(contract.request_model, BaseModel)
    assert isinstance(contract.check(good), contract.request_model)
    with pytest.raises(ValidationError) as refused:
        contract.check(bad)
    assert error_text(refused.value, model=contract.request_model).startswith(said)


def test_the_contracts_import_nothing_above_them_and_load_nothing_by_name() -> None:
    for path in sorted((ROOT / "secuav_common").rglob("*.py")):
        above = [m for m in _imports(path) if m.split(".")[0] in ABOVE_COMMON]
        assert above == [], f"{path.relative_to(ROOT)} imports {above}"
    for path in sorted((ROOT / "secuav_common" / "controlplane").rglob("*.py")):
        text = path.read_text()
        assert "importlib" not in _imports(path) and "argparse" not in _imports(path), path
        assert "import_module" not in text, path


def test_no_stage_imports_the_control_code() -> None:
    for path in sorted((ROOT / "mitm_proxy" / "stages").rglob("*.py")):
        control = [m for m in _imports(path) if m.startswith(("mitm_proxy.control", "mitm_proxy.tools"))]
        assert control == [], f"{path.relative_to(ROOT)} imports {control}"
