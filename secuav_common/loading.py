"""Read YAML/JSON documents into pydantic models with one clear error.

Every file a user hands us (scenario, attack profile, proxy config) goes
through :func:`load_model`, so every bad input is reported the same way: the
file, the dotted field path and the offending value, on one line, never a
traceback.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

M = TypeVar("M", bound=BaseModel)

MAX_DOCUMENT_BYTES = 1_000_000


class InputError(ValueError):
    """A user-supplied document is unreadable or invalid.

    ``str(err)`` is a single line naming source, field and value.
    """

    def __init__(self, source: str, field: str, value: Any, reason: str) -> None:
        self.source = source
        self.field = field
        self.value = value
        self.reason = reason
        where = f"{source}: {field}" if field else source
        shown = _short_repr(value)
        super().__init__(f"{where}: {reason}" + (f" (got {shown})" if shown else ""))


def _short_repr(value: Any, limit: int = 80) -> str:
    if value is _MISSING:
        return ""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


class _Missing:
    def __repr__(self) -> str:
        return "<missing>"


_MISSING: Any = _Missing()


def field_path(loc: tuple[int | str, ...]) -> str:
    """Turn a pydantic error location into ``rules[2].target.message``."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


def first_error(err: ValidationError, source: str) -> InputError:
    """Convert the first pydantic error into an :class:`InputError`."""
    detail = err.errors(include_url=False)[0]
    # Drop the discriminator tags pydantic inserts for tagged unions
    # (e.g. ``rules.0.bias.offset_m``): users never wrote them.
    loc = tuple(p for p in detail["loc"] if not (isinstance(p, str) and "[" in p))
    value = detail.get("input", _MISSING)
    if detail["type"] == "missing" or not loc:
        # A cross-field check on the whole document names field and value in its message.
        value = _MISSING
    reason = detail["msg"]
    if reason.startswith("Value error, "):
        reason = reason[len("Value error, ") :]
    return InputError(source, field_path(loc), value, reason)


class _NoAliasLoader(yaml.SafeLoader):
    """A YAML loader that refuses anchors and aliases: ``&a [*a, *a, ...]`` nested a few levels deep
    ("billion laughs") expands a few hundred bytes into gigabytes, so untrusted text may not use them."""

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise yaml.composer.ComposerError(
                None, None, "YAML aliases (*name) are not accepted here", event.start_mark
            )
        return super().compose_node(parent, index)


def parse_document(text: str | bytes, source: str, *, trusted: bool = True) -> Any:
    """Parse YAML (a superset of JSON) text into plain Python data.

    ``trusted=False`` (text from the network) refuses YAML aliases, so a small
    message cannot expand into an unbounded document.
    """
    if len(text) > MAX_DOCUMENT_BYTES:
        raise InputError(source, "", _MISSING, f"document larger than {MAX_DOCUMENT_BYTES} bytes")
    if isinstance(text, bytes):
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise InputError(source, "", _MISSING, f"not UTF-8 text (byte {exc.start})") from None
    try:
        return yaml.load(text, Loader=yaml.SafeLoader if trusted else _NoAliasLoader)
    except RecursionError:
        raise InputError(source, "", _MISSING, "nested too deeply") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1} column {mark.column + 1}" if mark else "document"
        problem = getattr(exc, "problem", None) or "invalid YAML/JSON"
        raise InputError(source, "", _MISSING, f"{problem} at {where}") from None


def parse_params(pairs: Iterable[str], flag: str = "--param") -> dict[str, Any]:
    """``--param NAME=VALUE`` as every command reads it, the value YAML (so JSON too):
    ``["links=[11,14]", "offset_m=2"]`` -> ``{"links": [11, 14], "offset_m": 2}``; ``NAME=`` is null."""
    out: dict[str, Any] = {}
    for pair in pairs:
        name, sep, raw = pair.partition("=")
        if not sep or not name:
            raise InputError(flag, "", pair, "expected NAME=VALUE")
        out[name] = parse_document(raw, f"{flag} {name}") if raw else None
    return out


def validate(model: type[M], data: Any, source: str) -> M:
    """Validate already-parsed data, raising :class:`InputError`."""
    if data is None:
        raise InputError(source, "", _MISSING, "document is empty")
    try:
        return model.model_validate(data)
    except ValidationError as err:
        raise first_error(err, source) from None


def load_model(model: type[M], path: str | Path) -> M:
    """Read ``path`` (YAML or JSON) and validate it as ``model``."""
    path = Path(path)
    source = str(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(source, "", _MISSING, exc.strerror or str(exc)) from None
    return validate(model, parse_document(raw, source), source)


def dump_json(model: BaseModel) -> str:
    """Canonical JSON of a model (stable key order), e.g. for hashing."""
    return json.dumps(model.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))
