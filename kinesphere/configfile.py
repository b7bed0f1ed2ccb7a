"""Typed config files: TOML (or already-parsed data) decoded into msgspec Structs.

A config file's schema is a tree of ``msgspec.Struct`` types with ``forbid_unknown_fields``,
``Literal``/``StrEnum`` names and ``Annotated[..., msgspec.Meta(...)]`` bounds; msgspec does
the checking. This module only turns msgspec's terse errors into KinesphereErrors that name
the file, the field and what would be valid, e.g.
``mapping mine.toml: controller.buttons.deadman[1]: 'lb'; valid: a, b, back, ...``.
Array positions count from 1, as people count ``[[step]]`` tables. A ``Meta`` may carry
``description`` (the phrase used for "must be ...") and ``extra={"code": ...}`` (the error
code for that field instead of the file's). Rules a schema cannot say (a label must exist in
the eURDF) stay with the module that owns the file, after decoding.
"""

from __future__ import annotations

import re
import tomllib
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import msgspec
import msgspec.inspect as mi

from kinesphere.errors import KinesphereError, choices

T = TypeVar("T")

_AT = re.compile(r"^(?P<problem>.*?)(?: - at (?:`key` in )?`(?P<path>\$[^`]*)`)?$", re.S)
_SEGMENT = re.compile(r"\.([^.\[]+)|\[(\d+|\.\.\.)\]")
_WORDS = {
    "int": "an integer", "float": "a number", "str": "a string", "bool": "true or false",
    "array": "a list", "object": "a table", "null": "nothing",
}


def _word(name: str) -> str:
    return " or ".join(_WORDS.get(n.strip(), n.strip()) for n in name.split("|"))


def _steps(path: str) -> list[str | int | None]:
    """``$.a.b[0][...]`` -> ``["a", "b", 0, None]`` (None: some key of a table)."""
    return [
        m[1] if m[1] is not None else (None if m[2] == "..." else int(m[2]))
        for m in _SEGMENT.finditer(path[1:])
    ]


def _show(steps: list[Any]) -> str:
    out = ""
    for s in steps:
        if isinstance(s, int):
            out += f"[{s + 1}]"
        elif s is None:
            out += "[...]"
        else:
            out += f".{s}" if out else s
    return out


def _members(t: mi.Type) -> list[mi.Type]:
    """``t`` without its metadata wrapper, unions split into their members."""
    while isinstance(t, mi.Metadata):
        t = t.type
    if isinstance(t, mi.UnionType):
        return [m for u in t.types for m in _members(u)]
    return [t]


def _metas(t: mi.Type) -> list[mi.Metadata]:
    """The metadata on ``t`` and on each member of a union ``t`` is."""
    out = []
    while isinstance(t, mi.Metadata):
        out.append(t)
        t = t.type
    if isinstance(t, mi.UnionType):
        out += [x for u in t.types for x in _metas(u)]
    return out


def _child(t: mi.Type, step: str | int | None) -> list[mi.Type]:
    """The types reachable from ``t`` through one path step."""
    out: list[mi.Type] = []
    for m in _members(t):
        if isinstance(step, str) and isinstance(m, (mi.StructType, mi.DataclassType)):
            out += [f.type for f in m.fields if f.encode_name == step]
        elif isinstance(step, int) and isinstance(m, (mi.ListType, mi.VarTupleType)):
            out.append(m.item_type)
        elif isinstance(step, int) and isinstance(m, mi.TupleType) and step < len(m.item_types):
            out.append(m.item_types[step])
        elif isinstance(m, mi.DictType) and not isinstance(step, int):
            out.append(m.value_type)
    return out


def _kind(value: Any) -> str:
    """msgspec's name for the type of a decoded TOML/JSON value."""
    names = {bool: "bool", int: "int", float: "float", str: "str", list: "array", dict: "object"}
    return "null" if value is None else names.get(type(value), type(value).__name__)


def _resolve(
    data: Any, steps: list[str | int | None], fits: Callable[[Any], bool] = lambda v: True
) -> tuple[Any, list[Any]]:
    """The value at ``steps`` in ``data`` (``...`` when absent), and the steps with each
    unnamed table key (msgspec's ``[...]``) named where only one key leads to a value that
    ``fits`` the error."""
    if not steps:
        return data, []
    head, rest = steps[0], steps[1:]
    if head is None and isinstance(data, Mapping):
        found = [(k, _resolve(v, rest, fits)) for k, v in data.items()]
        found = [(k, r) for k, r in found if r[0] is not ... and fits(r[0])]
        if len(found) == 1:
            key, (value, named) = found[0]
            return value, [key, *named]
        return ..., steps
    if isinstance(data, Mapping) and isinstance(head, str) and head in data:
        value, named = _resolve(data[head], rest, fits)
        return value, [head, *named]
    if isinstance(data, list) and isinstance(head, int) and head < len(data):
        value, named = _resolve(data[head], rest, fits)
        return value, [head, *named]
    return ..., steps


def _explain(
    exc: msgspec.ValidationError, data: Any, root: mi.Type, name_lists: bool
) -> tuple[str, str | None]:
    """(message, error code or None) for a validation error of ``data`` against ``root``."""
    m = _AT.match(str(exc))
    assert m is not None  # the pattern matches any text
    problem, path = m["problem"], m["path"] or "$"
    at_key = "`key` in" in str(exc)
    steps = _steps(path)
    types = [root]
    metas: list[mi.Metadata] = []
    for s in steps:
        types = [c for t in types for c in _child(t, s)]
        metas += [x for t in types for x in _metas(t)]
    code = next((x.extra["code"] for x in reversed(metas) if x.extra and "code" in x.extra), None)
    here = [x for t in types for x in _metas(t)]
    description = next(
        (x.extra_json_schema["description"] for x in here
         if x.extra_json_schema and "description" in x.extra_json_schema), None)
    enum = re.match(r"Invalid enum value (.*)$", problem)
    typed = re.match(r"Expected `[^`]*`, got `([^`]*)`$", problem)
    if enum and not at_key:
        value, named = _resolve(data, steps, lambda v: repr(v) == enum[1])
    elif typed:
        value, named = _resolve(data, steps, lambda v: _kind(v) == typed[1])
    else:
        value, named = _resolve(data, steps)
    where = _show(named) if steps else ""
    at = f"{where}: " if where else ""
    subject = where or "the file"
    got = "" if value is ... else f", got {value!r}"
    fields = [f for t in types for x in _members(t)
              if isinstance(x, (mi.StructType, mi.DataclassType)) for f in x.fields]
    keys = list(value) if isinstance(value, Mapping) else []
    if unknown := re.match(r"Object contains unknown field `(.*)`$", problem):
        valid = [f.encode_name for f in fields]
        extra = sorted(set(keys) - set(valid)) or [unknown[1]]
        names = repr(extra) if name_lists else ", ".join(extra)
        return f"{at}unknown {names}; valid: {choices(valid)}", code
    if missing := re.match(r"Object missing required field `(.*)`$", problem):
        absent = [f.encode_name for f in fields if f.required and f.encode_name not in keys]
        names = repr(absent or [missing[1]]) if name_lists else missing[1]
        need = next((d for f in fields if f.encode_name == missing[1] for x in _metas(f.type)
                     if x.extra_json_schema and (d := x.extra_json_schema.get("description"))),
                    None)
        return f"{at}missing {names}" + (f" ({need})" if need else ""), code
    if enum:
        if at_key:
            key_types = [x for t in types for d in _members(t) if isinstance(d, mi.DictType)
                         for x in _members(d.key_type)]
            valid = [v for k in key_types for v in _choices(k)]
            return f"{at}unknown {enum[1].strip(chr(39))}; valid: {choices(valid)}", code
        valid = [v for t in types for x in _members(t) for v in _choices(x)]
        return f"{at}{enum[1]}; valid: {choices(valid)}", code
    if description is not None and problem.startswith("Expected"):
        return f"{subject} must be {description}{got}", code
    if expected := re.match(r"Expected `([^`]*)`, got `([^`]*)`$", problem):
        return f"{subject} must be {_word(expected[1])}{got}", code
    if bound := re.match(r"Expected `([^`]*)` (.*)$", problem):
        return f"{subject} must be {_word(bound[1])} {bound[2]}{got}", code
    return f"{at}{problem}", code


def _choices(t: mi.Type) -> list[str]:
    if isinstance(t, mi.LiteralType):
        return [str(v) for v in t.values]
    if isinstance(t, mi.EnumType):
        return [str(member.value) for member in t.cls]
    return []


def convert(
    data: Any, type_: type[T], source: str, code: str = "malformed", *, name_lists: bool = False
) -> T:
    """``data`` (parsed TOML or JSON) as ``type_``; KinesphereError naming ``source`` and the
    field otherwise. KinesphereErrors raised by the types' ``__post_init__`` get ``source``.
    ``name_lists`` writes unknown and missing keys as a list of every one (``unknown
    ['colour']``) rather than the first (``unknown colour``)."""
    try:
        return msgspec.convert(data, type_, strict=True)
    except msgspec.ValidationError as exc:
        message, field_code = _explain(exc, data, mi.type_info(type_), name_lists)
        raise KinesphereError(field_code or code, f"{source}: {message}") from None
    except KinesphereError as exc:
        raise KinesphereError(exc.code, f"{source}: {exc.message}") from None


def parse_toml(text: str, source: str, code: str = "malformed") -> dict[str, Any]:
    """TOML text as a dict; invalid TOML raises KinesphereError naming ``source``."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise KinesphereError(code, f"{source} is not TOML: {exc}") from None


def read_toml(path: str | Path, what: str, code: str = "malformed") -> dict[str, Any]:
    """A TOML file as a dict; unreadable or invalid files raise KinesphereError naming it."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise KinesphereError(code, f"cannot read {what} {path}: {exc.strerror}") from None
    return parse_toml(text, f"{what} {path}", code)


def load_toml(
    path: str | Path, type_: type[T], what: str, code: str = "malformed", *,
    name_lists: bool = False,
) -> T:
    """A TOML file decoded as ``type_`` (see :func:`convert`)."""
    data = read_toml(path, what, code)
    return convert(data, type_, f"{what} {path}", code, name_lists=name_lists)


