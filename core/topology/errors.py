"""Turning YAML and pydantic errors into ``file:line:col: field.path: message`` lines."""

from __future__ import annotations

import re
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel


@dataclass(frozen=True)
class ConfigIssue:
    file: str
    line: int | None
    column: int | None
    path: str
    message: str

    def __str__(self) -> str:
        where = self.file
        if self.line is not None:
            where += f":{self.line}:{self.column or 1}"
        return f"{where}: {self.path}: {self.message}" if self.path else f"{where}: {self.message}"


class TopologyError(Exception):
    """The topology is invalid; ``issues`` lists every problem found."""

    def __init__(self, issues: list[ConfigIssue]):
        self.issues = issues
        super().__init__("\n".join(str(i) for i in issues))


def char_position(text: str, offset: int) -> tuple[int, int]:
    """1-based (line, column) of a character offset in ``text``."""
    return text.count("\n", 0, offset) + 1, offset - text.rfind("\n", 0, offset)


def byte_position(raw: bytes, offset: int) -> tuple[int, int]:
    """1-based (line, column in characters) of a byte offset in UTF-8 ``raw`` (valid up to ``offset``)."""
    start = raw.rfind(b"\n", 0, offset) + 1
    return raw.count(b"\n", 0, offset) + 1, len(raw[start:offset].decode("utf-8", "replace")) + 1


MAPPING_EXPECTED = "the file must be a mapping with keys gateway, fronts, backs"


def _ini_hint(text: str) -> str:
    """``; is it an INI or TOML file?`` when ``text`` has ``[section]`` or ``key = value`` parts."""
    return (
        "; is it an INI or TOML file?"
        if re.search(r"(^|\s)(\[[^\]\n]*\](\s|$)|[\w.-]+\s*=)", text)
        else ""
    )


def not_a_mapping(data: Any) -> str:
    """The message for a document whose top level is not a mapping."""
    if data is None:
        got = "an empty file"
    elif isinstance(data, str):
        got = f"text{_ini_hint(data)}"
    elif isinstance(data, list):
        got = "a list"
    else:
        got = repr(data)
    return f"not a YAML mapping: {MAPPING_EXPECTED} (got {got})"


def yaml_problem(exc: Any, text: str) -> str:
    """A ruamel ``MarkedYAMLError`` as one readable message, with hints for the usual causes."""
    problem = (exc.problem or "invalid YAML").strip()
    problem = re.sub(r"\('([^']*)',\)", r"\1", problem)  # ruamel prints some tokens as 1-tuples
    if "duplicate key" in problem:
        start = exc.context_mark
        return f"YAML syntax: {problem.split(' with value')[0]} in the mapping that starts on line {start.line + 1}; each key may appear once"
    if problem.startswith("expected '<document start>'"):
        return f"not a YAML mapping: {MAPPING_EXPECTED}; this line cannot continue the value the file starts with{_ini_hint(text)}"
    mark = exc.problem_mark
    if "'\\t'" in problem and mark is not None:
        lines = text.splitlines()
        before = lines[mark.line][: mark.column] if mark.line < len(lines) else ""
        problem += (
            " (YAML indents with spaces, not tabs)"
            if not before.strip()
            else " (YAML separates with spaces, not tabs)"
        )
    return f"YAML syntax: {problem}"


def dotted(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def position(
    root: Any, loc: tuple[Any, ...], *, key: bool = False
) -> tuple[int | None, int | None]:
    """1-based (line, column) of the node at ``loc`` in a ruamel document.

    Parts of ``loc`` that are not keys of the data (pydantic's union tags) are skipped.
    When the path ends at a missing key, the position of the innermost existing
    mapping is returned. ``key`` asks for the key's position rather than its value's.
    """
    node, best = root, _own_position(root)
    parts = [p for p in loc]
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        if isinstance(node, dict) and part in node:
            lc = getattr(node, "lc", None)
            child = node[part]
            if not (key and last) and not _is_scalar(child) and _own_position(child)[0] is not None:
                best = _own_position(child)  # inside a nested mapping or list: point at its content
            elif lc is not None:
                try:
                    line, col = (
                        lc.key(part) if (key and last) or not _is_scalar(child) else lc.value(part)
                    )
                    best = (line + 1, col + 1)
                except (KeyError, TypeError):
                    pass
            node = child
        elif isinstance(node, list) and isinstance(part, int) and 0 <= part < len(node):
            lc = getattr(node, "lc", None)
            if lc is not None:
                try:
                    line, col = lc.item(part)
                    best = (line + 1, col + 1)
                except (KeyError, TypeError):
                    pass
            node = node[part]
        # anything else is a union tag or a missing key: stay where we are
    return best


def _own_position(node: Any) -> tuple[int | None, int | None]:
    lc = getattr(node, "lc", None)
    if lc is None or lc.line is None:
        return (None, None)
    return (lc.line + 1, lc.col + 1)


def _is_scalar(value: Any) -> bool:
    return not isinstance(value, (dict, list))


def data_loc(root: Any, loc: tuple[Any, ...]) -> tuple[Any, ...]:
    """``loc`` with pydantic's union tags removed: only parts that address the data."""
    out, node = [], root
    for part in loc:
        if isinstance(node, dict) and part in node:
            out.append(part)
            node = node[part]
        elif isinstance(node, list) and isinstance(part, int) and 0 <= part < len(node):
            out.append(part)
            node = node[part]
        elif (
            not isinstance(node, (dict, list))
            or (isinstance(part, str) and part[:1].isupper())
            or "[" in str(part)
        ):
            continue  # union tag (class name or literal[...]), or below a scalar
        else:
            out.append(part)  # a missing key: keep it so the path names it
    return tuple(out)


def _unwrap(annotation: Any) -> list[Any]:
    """Candidate model classes behind an annotation (Optional, list, dict, Annotated, unions)."""
    origin = typing.get_origin(annotation)
    if origin is typing.Annotated:
        return _unwrap(typing.get_args(annotation)[0])
    if origin in (typing.Union, types.UnionType):
        return [c for arg in typing.get_args(annotation) for c in _unwrap(arg)]
    if origin in (list, tuple, set, frozenset):
        return [c for arg in typing.get_args(annotation) for c in _unwrap(arg)]
    if origin is dict:
        args = typing.get_args(annotation)
        return _unwrap(args[1]) if len(args) == 2 else []
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return []


def _holders(model: type[BaseModel], loc: tuple[Any, ...]) -> list[type[BaseModel]]:
    """The models that may hold the last element of ``loc``."""
    candidates: list[type[BaseModel]] = [model]
    for part in loc[:-1]:
        nxt: list[type[BaseModel]] = []
        for cls in candidates:
            if isinstance(part, str) and part in cls.model_fields:
                nxt.extend(_unwrap(cls.model_fields[part].annotation))
            elif isinstance(part, str) and part == cls.__name__:
                nxt.append(cls)
        if nxt:
            candidates = nxt
        # ints (list indexes) and dict keys keep the candidates already unwrapped
    return candidates


def allowed_keys(model: type[BaseModel], loc: tuple[Any, ...]) -> list[str]:
    """Field names accepted at the mapping that holds the last element of ``loc``."""
    keys: list[str] = []
    for cls in _holders(model, loc):
        for name, info in cls.model_fields.items():
            keys.append(info.alias or name)
    return sorted(set(keys))


def suggest(word: str, choices: list[str]) -> str:
    import difflib  # only when a name is wrong

    close = difflib.get_close_matches(word, choices, n=1, cutoff=0.6)
    return f"; did you mean '{close[0]}'?" if close else ""


def error_loc(err: Mapping[str, Any]) -> tuple[Any, ...]:
    """Where a pydantic error is: its ``loc``, and below it the ``loc`` tuple of the error's
    context if any. A model validator that checks one field among several raises
    ``PydanticCustomError(kind, message, {"loc": ("counts", "di")})`` to be reported there."""
    extra = (err.get("ctx") or {}).get("loc")
    return tuple(err["loc"]) + (tuple(extra) if isinstance(extra, (tuple, list)) else ())


def describe_pydantic_error(
    err: Mapping[str, Any], model: type[BaseModel], raw_loc: tuple[Any, ...]
) -> str:
    kind = err["type"]
    if kind == "extra_forbidden":
        field_name = str(raw_loc[-1])
        keys = allowed_keys(model, raw_loc)
        hint = suggest(field_name, keys)
        return (
            f"unknown field '{field_name}'{hint or ''} (expected one of: {', '.join(keys)})"
            if not hint
            else f"unknown field '{field_name}'{hint}"
        )
    if kind == "missing":
        descriptions = {
            info.description
            for cls in _holders(model, raw_loc)
            for name, info in cls.model_fields.items()
            if raw_loc and (info.alias or name) == raw_loc[-1] and info.description
        }
        return "required field is missing" + (
            f" ({descriptions.pop()})" if len(descriptions) == 1 else ""
        )
    message: str = err["msg"]
    if (
        kind == "value_error"
    ):  # a validator's own message: pydantic's "Value error, " prefix says nothing
        message = message.removeprefix("Value error, ")
    if "input" in err and not isinstance(err["input"], (dict, list)):
        message += f" (got {err['input']!r})"
    return message
