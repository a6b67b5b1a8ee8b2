"""The profile document: a name, a clock, a seed, optional parameters and a list of rules.

Reading a profile is all-or-nothing: pydantic checks types and ranges, then
:func:`check_profile` checks what the schema cannot express (the field exists
on the message, windows are ordered, the coordinated spoof targets anchors).
Any failure is one :class:`~secuav_common.loading.InputError` naming the file,
the rule's place (``rules[2].target.field``) and the bad value; a profile that
was returned is complete and valid.

Parameters make a profile a template: ``parameters: {links: {default: [10, 13]}}``
declares one, and a value written exactly ``"$links"`` anywhere in the rules is
replaced by it before validation (the library's ``type-a`` takes its attacked
links this way).
"""

from __future__ import annotations

import hashlib
import json
import operator
import re
from functools import reduce
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, JsonValue, PrivateAttr, ValidationError, create_model

from attack_profiles.primitives import BUILTIN_KINDS, PRIMITIVES, Primitive, kinds, load_all, primitive
from attack_profiles.rule import Strict
from secuav_common.loading import (
    _MISSING,  # the "no value to show" sentinel InputError understands
    MAX_DOCUMENT_BYTES,
    InputError,
    dump_json,
    parse_document,
)
from secuav_common.plugins import PluginError


def _rule_union(classes: list[type[Primitive]]) -> Any:
    """One discriminated union over these primitives' rule models (on ``kind``)."""
    return Annotated[reduce(operator.or_, (cls.rule_model for cls in classes)), Field(discriminator="kind")]


# The built-ins' union; the profile model's own grows with every primitive the registry enters
# (a plugin's, when a profile names it: see _accept), so a new primitive is declared once, in its module.
Rule = _rule_union(list(PRIMITIVES.values()))


class Parameter(Strict):
    """A template parameter: its default value and what it means."""

    default: JsonValue
    description: str = ""


class Profile(Strict):
    """An attack profile (see attack_profiles/README.md)."""

    name: Annotated[str, Field(min_length=1, max_length=100)]
    description: str = ""
    clock: Literal["activation", "vehicle"] = Field(
        "activation",
        description="activation: seconds since the profile became active; vehicle: the stream's time_boot_ms",
    )
    seed: int = Field(0, ge=0, lt=2**63, description="seeds noise, drop and garbage; with the engine's seed")
    parameters: dict[str, Parameter] = Field(default_factory=dict)
    rules: list[Rule] = Field(default_factory=list)  # type: ignore[valid-type]

    _source: str = PrivateAttr("<profile>")

    @property
    def source(self) -> str:
        """Where the profile was read from (file path, ``library:NAME``, ``<mqtt>``)."""
        return self._source

    def __eq__(self, other: object) -> bool:
        # Equal content is equal, whichever file, topic or library name it came from.
        return isinstance(other, Profile) and self.canonical_json() == other.canonical_json()

    def __hash__(self) -> int:
        return hash(self.canonical_json())

    def __setstate__(self, state: dict[Any, Any]) -> None:
        # Unpickled in another process (a Dask worker): the rules' primitives must be known there too,
        # for the engine and for this model to serialise them.
        super().__setstate__(state)
        _know_rules(self)

    def canonical_json(self) -> str:
        _know_rules(self)
        return dump_json(self)

    def content_hash(self) -> str:
        """SHA-256 of the canonical JSON: equal for equal profiles, whatever their source or spelling."""
        return hashlib.sha256(self.canonical_json().encode()).hexdigest()


_MODEL_KINDS: tuple[str, ...] = tuple(PRIMITIVES)  # the kinds the Profile model is built with now


def _sync_model() -> None:
    """Rebuild the profile model's rule union when the registry has entered new primitives."""
    global _MODEL_KINDS
    if tuple(PRIMITIVES) == _MODEL_KINDS:
        return
    Profile.model_fields["rules"].annotation = list[_rule_union(list(PRIMITIVES.values()))]  # type: ignore[misc]
    Profile.model_rebuild(force=True)
    _MODEL_KINDS = tuple(PRIMITIVES)


def _primitive_of(rule: Any) -> type[Primitive] | None:
    """The primitive class whose rule model ``rule`` is an instance of (for a rule built in another process)."""
    found = primitive(rule.kind)
    if found is not None:
        return found
    todo = list(Primitive.__subclasses__())
    while todo:
        cls = todo.pop()
        if getattr(cls, "rule_model", None) is type(rule):
            PRIMITIVES[cls.kind] = cls
            return cls
        todo += cls.__subclasses__()
    return None


def _know_rules(profile: Profile) -> None:
    """Enter the primitives of ``profile``'s rules in the registry and the model (cheap when they are known)."""
    if all(rule.kind in PRIMITIVES for rule in profile.rules):  # type: ignore[attr-defined]
        if tuple(PRIMITIVES) != _MODEL_KINDS:
            _sync_model()
        return
    for rule in profile.rules:
        if rule.kind not in PRIMITIVES:  # type: ignore[attr-defined]
            _primitive_of(rule)
    _sync_model()


def _accept(data: dict[str, Any], source: str) -> dict[str, Any]:
    """Enter the plugin primitives the rules name, spelling a ``module:Class`` kind as the class's own kind."""
    rules = data.get("rules")
    if not isinstance(rules, list):
        return data
    out: list[Any] = []
    for i, rule in enumerate(rules):
        kind = rule.get("kind") if isinstance(rule, dict) else None
        if isinstance(kind, str) and kind not in PRIMITIVES:
            try:
                cls = primitive(kind)
            except PluginError as exc:
                raise InputError(source, f"rules[{i}].kind", kind, str(exc)) from None
            if cls is not None and cls.kind != kind:
                rule = {**rule, "kind": cls.kind}
        out.append(rule)
    _sync_model()
    return {**data, "rules": out}


def _path(loc: tuple[int | str, ...] | list[int | str]) -> str:
    """``rules[2].target.field``; a key that is not a plain name is quoted: ``rules[0]['']``."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif part.isidentifier():
            out += ("." if out else "") + part
        else:
            out += f"[{part!r}]"
    return out


def _user_path(loc: tuple[int | str, ...], data: Any) -> tuple[list[int | str], int]:
    """The parts of a pydantic error location that exist in the user's document, and how many matched.

    pydantic inserts union member tags (``rules.0.bias.offset``,
    ``target.sensor_id.constrained-int``) that users never wrote; walking the
    document tells them apart from real keys. A final key or index missing from
    its container is kept: it is the missing field itself.
    """
    out: list[int | str] = []
    matched = 0
    cur = data
    last = len(loc) - 1
    for i, part in enumerate(loc):
        in_dict = isinstance(cur, dict) and part in cur
        in_list = isinstance(cur, list) and isinstance(part, int) and 0 <= part < len(cur)
        if in_dict or in_list:
            cur = cur[part]  # type: ignore[index]
            matched += 1
        elif i == last and isinstance(cur, dict) and isinstance(part, str) and part.isidentifier():
            if part in PRIMITIVES or part[0].isupper() or part in ("int", "float", "str", "bool", "none"):
                continue  # a union member's tag, not a missing key
        elif not (i == last and isinstance(cur, list) and isinstance(part, int)):
            continue
        out.append(part)
    return out, matched


def _to_input_error(err: ValidationError, data: Any, source: str) -> InputError:
    """The most specific pydantic error as one InputError naming ``rules[i].field`` as the user wrote it.

    For a value that fits none of a union's members pydantic reports one error per
    member; the one that reaches deepest into what the user wrote explains it best
    (a mapping given for ``sensor_id`` is judged as an id range, not as an integer).
    """
    details = err.errors(include_url=False)
    paths = [_user_path(tuple(d["loc"]), data) for d in details]
    best = max(range(len(details)), key=lambda i: (paths[i][1], len(paths[i][0])))  # first of the deepest
    detail, loc = details[best], paths[best][0]
    known = ", ".join(kinds())
    if detail["type"] == "union_tag_not_found":
        return InputError(source, _path((*loc, "kind")), _MISSING, f"missing; one of {known}")
    if detail["type"] == "union_tag_invalid":
        tag = detail.get("input")
        tag = tag.get("kind") if isinstance(tag, dict) else tag
        return InputError(source, _path((*loc, "kind")), tag, f"unknown primitive; one of {known}")
    value = detail.get("input", _MISSING) if loc and detail["type"] != "missing" else _MISSING
    reason = detail["msg"].removeprefix("Value error, ")
    return InputError(source, _path(loc), value, reason)


_PLACEHOLDER = re.compile(r"\$[A-Za-z_][A-Za-z0-9_]*")  # "$links"; "$5 budget" in a note stays text


def _substitute(node: Any, values: dict[str, Any], path: str, source: str) -> Any:
    if isinstance(node, str) and _PLACEHOLDER.fullmatch(node):
        name = node[1:]
        if name not in values:
            raise InputError(source, path, node, f"no parameter {name!r} (declared: {', '.join(values) or 'none'})")
        return values[name]
    if isinstance(node, dict):
        return {k: _substitute(v, values, f"{path}.{k}", source) for k, v in node.items()}
    if isinstance(node, list):
        return [_substitute(v, values, f"{path}[{i}]", source) for i, v in enumerate(node)]
    return node


def _apply_parameters(data: dict[str, Any], params: dict[str, Any], source: str) -> dict[str, Any]:
    declared = data.get("parameters") or {}
    if not isinstance(declared, dict):
        raise InputError(source, "parameters", declared, "must be a mapping of name to {default, description}")
    values: dict[str, Any] = {}
    for name, spec in declared.items():
        if not isinstance(spec, dict) or "default" not in spec:
            raise InputError(source, f"parameters.{name}", spec, "must be a mapping with a 'default'")
        values[str(name)] = spec["default"]
    for name, value in params.items():
        if name not in values:
            declared_names = ", ".join(values) or "none"
            raise InputError(source, name, value, f"not a parameter of this profile (declared: {declared_names})")
        values[name] = value
    if not values:
        return data
    # The resolved profile records the values it was built with, so it describes itself
    # and parses back to the same profile (and the same content hash).
    resolved = {name: {**spec, "default": values[str(name)]} for name, spec in declared.items()}
    out = {**data, "parameters": resolved}
    if "rules" in data:
        out["rules"] = _substitute(data["rules"], values, "rules", source)
    return out


def check_profile(profile: Profile, source: str) -> None:
    """Every rule's own checks, in order; the first failure is raised."""
    for i, rule in enumerate(profile.rules):
        rule.check(f"rules[{i}]", source)


def parse_text(text: str | bytes, source: str, trusted: bool = True) -> Any:
    """JSON first (what MQTT carries; the YAML parser mangles JSON's surrogate-pair escapes
    of characters beyond the BMP), YAML for everything else (without aliases unless ``trusted``)."""
    if len(text) <= MAX_DOCUMENT_BYTES:
        try:
            return json.loads(text)
        except (ValueError, RecursionError):
            pass
    return parse_document(text, source, trusted=trusted)


def parse_profile(data_or_text: Any, source: str = "<mqtt>", **params: Any) -> Profile:
    """Validate a profile given as text (YAML/JSON) or already-parsed data.

    ``params`` override the profile's declared parameters. Raises ``InputError``.
    """
    data = parse_text(data_or_text, source) if isinstance(data_or_text, str | bytes) else data_or_text
    if data is None:
        raise InputError(source, "profile", None, "document is empty")
    if not isinstance(data, dict):
        raise InputError(source, "profile", data, "a profile must be a mapping (name, rules, ...)")
    data = _accept(_apply_parameters(data, params, source), source)
    try:
        profile = Profile.model_validate(data)
    except ValidationError as err:
        raise _to_input_error(err, data, source) from None
    check_profile(profile, source)
    profile._source = source
    return profile


def load_profile(path: str | Path, **params: Any) -> Profile:
    """Read and validate a profile file (YAML or JSON); raises ``InputError``."""
    path = Path(path)
    source = str(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(source, "", _MISSING, exc.strerror or str(exc)) from None
    return parse_profile(parse_document(raw, source), source, **params)


SCHEMA_PATH = Path(__file__).resolve().parent / "schema" / "profile.schema.json"


def profile_json_schema(plugins: bool = False) -> dict[str, Any]:
    """The JSON Schema of a profile document: the built-in primitives' (as exported to
    ``schema/profile.schema.json``), or with ``plugins`` every primitive installed here."""
    if plugins:
        load_all()
        _sync_model()
        schema = Profile.model_json_schema()
    else:
        builtin = [cls for kind, cls in PRIMITIVES.items() if kind in BUILTIN_KINDS]
        rules = (list[_rule_union(builtin)], Field(default_factory=list))
        model = create_model("Profile", __base__=Profile, __doc__=Profile.__doc__, rules=rules)
        schema = model.model_json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["$id"] = "https://secuav.example/schema/profile.schema.json"
    return schema


def profile_schema_text(plugins: bool = False) -> str:
    """The exported schema file's exact content (a test keeps the file in step with the models)."""
    return json.dumps(profile_json_schema(plugins), indent=2, sort_keys=True) + "\n"
