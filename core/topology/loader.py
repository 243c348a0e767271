"""Loading and validating a topology file.

ruamel.yaml (YAML 1.2, round-trip loader) keeps the line and column of every key and
value and rejects duplicate keys, so one parse serves pydantic and the error report.
Each front and back entry is validated with the model its plugin registered for its
``type``; core then checks what spans sections (unique names, module addresses,
channels named by ``expose``).
"""

from __future__ import annotations

import copy
import fnmatch
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, TypeVar

from pydantic import BaseModel, Field, ValidationError
from ruamel.yaml import YAML
from ruamel.yaml.error import MarkedYAMLError, YAMLError
from ruamel.yaml.reader import ReaderError

from ..image import ChannelSpec
from .errors import (
    ConfigIssue,
    TopologyError,
    byte_position,
    char_position,
    data_loc,
    describe_pydantic_error,
    dotted,
    error_loc,
    not_a_mapping,
    position,
    suggest,
    yaml_problem,
)
from .guard import check_structure, read_limited
from .model import BackConfig, FrontConfig, GatewaySection, StrictModel


class _Root(StrictModel):
    gateway: GatewaySection
    models: dict[str, dict[str, Any]] = Field(
        default_factory=dict,
        description="device models by name, each with the type of back that reads it (modbus): "
        "defined once, named by modules' model",
    )
    fronts: list[dict[str, Any]] = Field(min_length=1)
    backs: list[dict[str, Any]] = Field(min_length=1)


@dataclass
class Topology:
    gateway: GatewaySection
    fronts: list[FrontConfig]
    backs: list[BackConfig]
    source: str = "<dict>"
    base_dir: Path = field(default_factory=Path.cwd)
    channel_specs: list[ChannelSpec] = field(default_factory=list)
    models: dict[str, Any] = field(default_factory=dict)  # name -> its plugin's validated model

    @property
    def state_dir(self) -> Path:
        return (self.base_dir / self.gateway.state_dir).resolve()

    def front(self, name: str) -> FrontConfig:
        return _by_name(self.fronts, name, "front")

    def back(self, name: str) -> BackConfig:
        return _by_name(self.backs, name, "back")

    def summary(self) -> str:
        from ..image import Kind

        counts = {k: sum(1 for s in self.channel_specs if s.kind is k) for k in Kind}
        modules = len(
            {(b.name, m.address) for b in self.backs for m in b.modules}
            | {(s.source.back, s.source.module) for s in self.channel_specs}
        )
        lines = [
            f"gateway {self.gateway.name}: {len(self.fronts)} front(s), {len(self.backs)} back(s), {modules} module(s), {len(self.channel_specs)} channel(s)",
            "  channels: "
            + ", ".join(
                f"{counts[k]} {k.value.upper()}" for k in Kind if counts[k] or not k.is_special
            ),
        ]
        for f in self.fronts:
            lines.append(f"  front {f.name} ({f.type})")
            lines += [f"    warning: {text}" for text in f.validation_warnings()]
        for b in self.backs:
            n = sum(1 for s in self.channel_specs if s.source.back == b.name)
            note = b.modules_note()
            count = f"{len(b.modules)} module(s)" if not note else f"modules {note}"
            lines.append(f"  back  {b.name} ({b.type}): {count}, {n} channel(s)")
            notes = getattr(b, "load_notes", None)
            lines += [f"    polls: {text}" for text in (notes() if notes is not None else [])]
        lines += [f"warning: {text}" for text in self.warnings()]
        return "\n".join(lines)

    def warnings(self) -> list[str]:
        """What is valid but will not work as configured (a line booked beyond its poll_ms), would
        not go back onto the box a front's style replaces (fronts' topology_warnings), and
        channels a front leaves out because it cannot carry their type."""
        out: list[str] = []
        for front in self.fronts:
            out += [f"front {front.name}: {text}" for text in front.topology_warnings(self)]
        for back in self.backs:
            check = getattr(back, "timing_warnings", None)
            if check is not None:
                out += check()
        for front in self.fronts:
            left = left_out(front, self.channel_specs)
            if left:
                types = ", ".join(sorted({s.data_type.value for s in left}))
                more = f" and {len(left) - 3} more" if len(left) > 3 else ""
                out.append(
                    f"fronts.{front.name}: {len(left)} channel(s) of a type a {front.type} front "
                    f"cannot carry ({types}) are left out of it: "
                    f"{', '.join(s.id for s in left[:3])}{more}"
                )
        return out


def left_out(front: FrontConfig, specs: list[ChannelSpec]) -> list[ChannelSpec]:
    """The channels ``front`` would serve by its ``expose`` (or all) whose type it cannot carry."""
    carried = front.carried_types
    if carried is None:
        return []
    return [
        s
        for s in specs
        if s.data_type not in carried
        and (front.expose is None or any(fnmatch.fnmatchcase(s.id, p) for p in front.expose))
    ]


class _ComponentType(Protocol):
    @property
    def model(self) -> type[FrontConfig] | type[BackConfig] | type[StrictModel]: ...

    def missing(self) -> str: ...  # an optional dependency it needs that is not installed


class ComponentTypes(Protocol):
    """What validation needs of the plugin registry (:class:`fieldgate.plugin.Registry` is one)."""

    def lookup(self, role: str, type_name: str) -> _ComponentType | None: ...

    def type_names(self, role: str) -> list[str]: ...

    def why_missing(self, role: str, type_name: str) -> str: ...  # plugins that failed, if any


class _Named(Protocol):
    name: str


T = TypeVar("T", bound=_Named)


def _by_name(items: list[T], name: str, what: str) -> T:
    for item in items:
        if item.name == name:
            return item
    raise KeyError(f"no {what} named {name!r} (have: {', '.join(i.name for i in items)})")


def read_yaml(path: str | Path) -> Any:
    """Parse a YAML file keeping positions; a file that is not a regular one or too big,
    bytes that are not UTF-8, syntax errors, duplicate keys, nesting too deep and aliases
    that expand too far become TopologyError (``guard.py``)."""
    file = str(path)
    raw = read_limited(file)  # a regular file of sane size (guard.py)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line, col = byte_position(raw, exc.start)
        raise TopologyError(
            [
                ConfigIssue(
                    file,
                    line,
                    col,
                    "",
                    f"not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start}); save the file as UTF-8",
                )
            ]
        ) from None
    yaml = YAML(typ="rt")
    try:
        check_structure(text, file)  # depth, alias expansion, duplicate keys: before building
        return yaml.load(text)
    except MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where: tuple[int | None, int | None] = (
            (mark.line + 1, mark.column + 1) if mark else (None, None)
        )
        raise TopologyError([ConfigIssue(file, *where, "", yaml_problem(exc, text))]) from None
    except (
        ReaderError
    ) as exc:  # a control character such as NUL; its position is an offset in the text
        line, col = char_position(text, exc.position)
        char = exc.character if isinstance(exc.character, int) else ord(exc.character)
        raise TopologyError(
            [
                ConfigIssue(
                    file,
                    line,
                    col,
                    "",
                    f"YAML syntax: character U+{char:04X} is not allowed in YAML text (is this a binary file?)",
                )
            ]
        ) from None
    except YAMLError as exc:
        raise TopologyError(
            [ConfigIssue(file, None, None, "", f"YAML syntax: {' '.join(str(exc).split())}")]
        ) from None


def apply_overrides(
    data: Any, overrides: dict[str, Any], origins: dict[tuple[Any, ...], str] | None = None
) -> Any:
    """Set fields by dotted path before validation: ``fronts.can.interface`` or ``backs.0.port``.

    A list element is addressed by index or by its ``name``. A path that addresses nothing
    raises KeyError with the message. ``origins``, if given, receives for each override the
    location it set (the first key it created, or the one it replaced) and its ``--set`` text.
    """
    for dotted_path, value in overrides.items():
        where = f"--set {dotted_path}={_show_value(value)}"
        parts = dotted_path.split(".")
        node = data
        loc: tuple[Any, ...] = ()
        created: tuple[Any, ...] | None = None
        for i, part in enumerate(parts):
            last = i == len(parts) - 1
            if isinstance(node, list):
                index = _list_index(node, part, ".".join(parts[:i]), where)
                loc += (index,)
                if last:
                    node[index] = value
                else:
                    node = node[index]
            elif isinstance(node, dict):
                loc += (part,)
                if part not in node and created is None:
                    created = loc
                if last:
                    node[part] = value
                else:
                    node = node.setdefault(part, {})
            else:
                raise KeyError(f"{where}: {'.'.join(parts[:i])} is not a mapping or list")
        if origins is not None:
            origins[created or loc] = where
    return data


def _show_value(value: Any) -> str:
    """A --set value as it would be typed: YAML scalars, flow collections."""
    if value is True or value is False:
        return "true" if value else "false"
    if value is None:
        return "null"
    if isinstance(value, dict):
        return (
            "{" + ", ".join(f"{_show_value(k)}: {_show_value(v)}" for k, v in value.items()) + "}"
        )
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_show_value(v) for v in value) + "]"
    return str(value)


def _list_index(items: list[Any], part: str, where_list: str, where: str) -> int:
    n = len(items)
    entries = f"{where_list} has {'no entries' if not n else '1 entry (index 0)' if n == 1 else f'{n} entries (index 0..{n - 1})'}"
    if part.removeprefix("-").isdigit():
        index = int(part)
        if not 0 <= index < n:
            raise KeyError(f"{where}: {entries}")
        return index
    names = [
        name
        for item in items
        if isinstance(item, dict) and isinstance(name := item.get("name"), str)
    ]
    for i, item in enumerate(items):
        if isinstance(item, dict) and item.get("name") == part:
            return i
    named = f", named {', '.join(repr(name) for name in names)}" if names else ""
    raise KeyError(f"{where}: no list entry named {part!r}; {entries}{named}{suggest(part, names)}")


def load_topology(
    source: str | Path | dict[str, Any],
    registry: ComponentTypes,
    overrides: dict[str, Any] | None = None,
) -> Topology:
    """Load and validate a topology from a YAML file or a dict. Raises TopologyError.

    An error at a field that an override set, or inside it, ends with ``(from --set PATH=VALUE)``.
    """
    if isinstance(source, dict):
        data, file, base_dir = copy.deepcopy(source), "<dict>", Path.cwd()
    else:
        data, file, base_dir = read_yaml(source), str(source), Path(source).resolve().parent
    origins: dict[tuple[Any, ...], str] = {}
    if overrides and isinstance(data, dict):
        wrong = []
        for path, value in overrides.items():
            try:
                apply_overrides(data, {path: value}, origins)
            except KeyError as exc:
                wrong.append(ConfigIssue(file, None, None, "", str(exc.args[0])))
        if wrong:
            raise TopologyError(wrong)
    try:
        return validate(data, registry, file, base_dir)
    except TopologyError as exc:
        if not origins:
            raise
        raise TopologyError([_from_override(issue, origins) for issue in exc.issues]) from None


def _from_override(issue: ConfigIssue, origins: dict[tuple[Any, ...], str]) -> ConfigIssue:
    for loc, where in origins.items():
        path = dotted(loc)
        if issue.path == path or issue.path.startswith((path + ".", path + "[")):
            return ConfigIssue(
                issue.file, issue.line, issue.column, issue.path, f"{issue.message} (from {where})"
            )
    return issue


def validate(
    data: Any, registry: ComponentTypes, file: str = "<dict>", base_dir: Path | None = None
) -> Topology:
    """Validate parsed YAML (ruamel nodes keep positions) or a plain dict; report every error.

    Field errors of every section are collected first; names and module addresses are checked
    for uniqueness alongside them. What needs the whole topology valid (channel ids,
    ``expose`` patterns) is checked last, only when nothing else is wrong.
    """
    issues: list[ConfigIssue] = []
    if not isinstance(data, dict):
        raise TopologyError([ConfigIssue(file, 1, 1, "", not_a_mapping(data))])
    root = None
    try:
        root = _Root.model_validate(data)
    except ValidationError as exc:
        issues.extend(_issues_from(exc, _Root, data, (), file))

    fronts: list[FrontConfig] = []
    backs: list[BackConfig] = []
    models: dict[str, Any] = {}
    checked_backs: dict[
        int, BackConfig | None
    ] = {}  # None: its own fields are wrong, not the back as a whole
    # base_dir: plugin configs resolve their own relative paths (a DCON scan file, a CSV map);
    # models: what a module's model names (validated first, by the plugin that registered its type)
    raw_models = data.get("models")
    context = {
        "base_dir": base_dir or Path.cwd(),
        "models": models,
        "model_names": {str(k) for k in raw_models} if isinstance(raw_models, dict) else set(),
    }
    sections: tuple[tuple[str, list[Any]], ...] = (
        ("model", []),
        ("front", fronts),
        ("back", backs),
    )
    for role, out in sections:
        for i, entry in _section_items(data, role):
            if not isinstance(entry, dict):
                continue  # reported above
            base = (f"{role}s", i)
            ctype = _component_type(registry, role, entry, data, base, file, issues)
            if ctype is None:
                continue
            missing = ctype.missing()
            if missing:
                line, col = position(data, base + ("type",))
                issues.append(ConfigIssue(file, line, col, dotted(base + ("type",)), missing))
                continue
            try:
                config = ctype.model.model_validate(dict(entry), context=context)
            except ValidationError as exc:
                found = _issues_from(exc, ctype.model, data, base, file)
                issues.extend(found)
                if role == "back" and all(issue.path != dotted(base) for issue in found):
                    checked_backs[i] = None
            else:
                if role == "model":
                    models[str(i)] = config
                    continue
                out.append(config)
                if role == "back" and isinstance(config, BackConfig):
                    checked_backs[i] = config
    issues.extend(_unique_checks(data, checked_backs, file))
    if issues or root is None:
        raise TopologyError(_dedupe(issues))

    topology = Topology(root.gateway, fronts, backs, file, base_dir or Path.cwd(), models=models)
    issues.extend(_cross_checks(topology, data, file))
    if issues:
        raise TopologyError(_dedupe(issues))
    return topology


def _section_items(data: dict[Any, Any], role: str) -> list[tuple[Any, Any]]:
    """The entries of ``models`` (a mapping) or of ``fronts``/``backs`` (lists), with their
    keys; none when the section is missing or of the wrong shape (the root model says so)."""
    entries = data.get(f"{role}s")
    if role == "model" and isinstance(entries, dict):
        return list(entries.items())
    if role != "model" and isinstance(entries, list):
        return list(enumerate(entries))
    return []


def _component_type(
    registry: ComponentTypes,
    role: str,
    entry: dict[Any, Any],
    data: Any,
    base: tuple[Any, ...],
    file: str,
    issues: list[ConfigIssue],
) -> _ComponentType | None:
    """The installed type an entry names; None, with the issue added, when it names none
    or one no plugin provides."""
    type_name = entry.get("type")
    if not isinstance(type_name, str):
        line, col = position(data, base)
        issues.append(
            ConfigIssue(
                file,
                line,
                col,
                dotted(base + ("type",)),
                f"required field is missing: the {role} type, one of: {', '.join(registry.type_names(role)) or '(none installed)'}",
            )
        )
        return None
    ctype = registry.lookup(role, type_name)
    if ctype is None:
        line, col = position(data, base + ("type",))
        installed = ", ".join(registry.type_names(role)) or "none"
        hint = suggest(type_name, registry.type_names(role))
        issues.append(
            ConfigIssue(
                file,
                line,
                col,
                dotted(base + ("type",)),
                f"no installed plugin provides {role} type '{type_name}'{hint} (installed {role} types: {installed})"
                + (registry.why_missing(role, type_name) or "; is the plugin installed?"),
            )
        )
    return ctype


def _issues_from(
    exc: ValidationError, model: type[BaseModel], data: Any, base: tuple[Any, ...], file: str
) -> list[ConfigIssue]:
    out = []
    for err in exc.errors(include_url=False):
        raw_loc = error_loc(err)
        full = base + data_loc(_at(data, base), raw_loc)
        line, col = position(data, full, key=err["type"] == "extra_forbidden")
        out.append(
            ConfigIssue(file, line, col, dotted(full), describe_pydantic_error(err, model, raw_loc))
        )
    return out


def _at(data: Any, loc: tuple[Any, ...]) -> Any:
    for part in loc:
        data = data[part]
    return data


def _dedupe(issues: list[ConfigIssue]) -> list[ConfigIssue]:
    """Merge the several errors pydantic reports for one field of a union into one line."""
    merged: dict[tuple[Any, ...], ConfigIssue] = {}
    for issue in issues:
        key = (issue.file, issue.line, issue.column, issue.path)
        if key in merged:
            prev = merged[key]
            if issue.message not in prev.message:
                merged[key] = ConfigIssue(
                    prev.file,
                    prev.line,
                    prev.column,
                    prev.path,
                    f"{prev.message}; or {issue.message}",
                )
        else:
            merged[key] = issue
    return sorted(merged.values(), key=lambda i: (i.line or 0, i.column or 0, i.path))


def _unique_checks(
    data: dict[str, Any], checked_backs: dict[int, BackConfig | None], file: str
) -> list[ConfigIssue]:
    """Names unique across fronts and backs, module addresses unique on each back.

    Run on the data as written, so that they are reported with the field errors. A back
    whose model validated gives its modules' addresses as validated; one whose fields are
    wrong gives the addresses that are integers; a back refused as a whole is left out
    (its plugin's check, e.g. DCON's own address check, said why).
    """
    issues: list[ConfigIssue] = []

    def issue(loc: tuple[Any, ...], message: str) -> None:
        line, col = position(data, loc)
        issues.append(ConfigIssue(file, line, col, dotted(loc), message))

    seen: dict[str, tuple[Any, ...]] = {}
    for section in ("fronts", "backs"):
        entries = data.get(section)
        for i, entry in enumerate(entries if isinstance(entries, list) else []):
            name = entry.get("name") if isinstance(entry, dict) else None
            if not isinstance(name, str):
                continue
            if name in seen:
                issue(
                    (section, i, "name"),
                    f"name '{name}' is already used by {dotted(seen[name])}; names must be unique across fronts and backs",
                )
            else:
                seen[name] = (section, i)

    for b_index, back in checked_backs.items():
        if back is not None:
            addresses: list[int | None] = [module.address for module in back.modules]
        else:
            modules = data["backs"][b_index].get("modules")
            addresses = [_address(m) for m in modules] if isinstance(modules, list) else []
        first: dict[int, int] = {}
        for m_index, address in enumerate(addresses):
            if address is None:
                continue
            if address in first:
                issue(
                    ("backs", b_index, "modules", m_index, "address"),
                    f"address {address} is already used by modules[{first[address]}] on this line",
                )
            else:
                first[address] = m_index
    return issues


def _address(module: Any) -> int | None:
    address = module.get("address") if isinstance(module, dict) else None
    return address if isinstance(address, int) and not isinstance(address, bool) else None


def _cross_checks(topology: Topology, data: Any, file: str) -> list[ConfigIssue]:
    """What needs every section valid: the backs' channels, and the fronts' ``expose`` patterns."""
    issues: list[ConfigIssue] = []

    def issue(loc: tuple[Any, ...], message: str) -> None:
        line, col = position(data, loc)
        issues.append(ConfigIssue(file, line, col, dotted(loc), message))

    for b_index, back in enumerate(topology.backs):
        try:
            topology.channel_specs.extend(back.channel_specs())
        except ValueError as exc:
            issue(("backs", b_index), str(exc))

    if issues:
        return issues  # channel ids are incomplete: checking expose would only add noise
    ids = {s.id for s in topology.channel_specs}
    # a back that finds its modules at start and has no scan file: its channel ids come later
    unknown = [
        b.name
        for b in topology.backs
        if b.finds_modules_at_start()
        and not any(s.source.back == b.name for s in topology.channel_specs)
    ]
    for f_index, front in enumerate(topology.fronts):
        for e_index, pattern in enumerate(front.expose or []):
            if not fnmatch.filter(ids, pattern) and not any(
                fnmatch.fnmatchcase(name, pattern.split("/", 1)[0]) for name in unknown
            ):
                close = suggest(pattern, sorted(ids))
                issue(
                    ("fronts", f_index, "expose", e_index),
                    f"'{pattern}' matches no channel{close or ''} (channel ids look like <back>/m<address>/<kind><index>, e.g. {next(iter(sorted(ids)), 'rs485/m1/di0')})",
                )
    _one_writer_checks(topology, issue)
    _carried_checks(topology, issue)
    if issues:
        return issues
    for f_index, front in enumerate(topology.fronts):
        for loc, message in front.check(topology):
            issue(("fronts", f_index, *loc), message)
    return issues


def _carried_checks(topology: Topology, issue: Callable[[tuple[Any, ...], str], None]) -> None:
    """A channel named by its id (not a glob) in the ``expose`` of a front that cannot carry its
    type is an error; a glob leaves such channels out (``Topology.warnings`` says which)."""
    types = {s.id: s.data_type for s in topology.channel_specs}
    for f_index, front in enumerate(topology.fronts):
        carried = front.carried_types
        if carried is None or front.expose is None:
            continue
        for e_index, entry in enumerate(front.expose):
            dtype = types.get(entry)
            if dtype is not None and dtype not in carried:
                issue(
                    ("fronts", f_index, "expose", e_index),
                    f"{entry} is {dtype.value}: a {front.type} front carries only "
                    f"{', '.join(sorted(t.value for t in carried))}; serve it from an opcua, "
                    "modbus-tcp or sparkplug front",
                )


def _one_writer_checks(topology: Topology, issue: Callable[[tuple[Any, ...], str], None]) -> None:
    """One output channel has one writing front: a second writer is an error naming both."""
    outputs = [s.id for s in topology.channel_specs if s.kind.is_output]
    writer: dict[str, int] = {}
    for f_index, front in enumerate(topology.fronts):
        patterns = front.written_outputs()
        field = "writable" if "writable" in type(front).model_fields else "expose"
        if patterns is not None and patterns is not front.expose:
            for p_index, pattern in enumerate(patterns):
                if not fnmatch.filter(outputs, pattern):
                    issue(
                        ("fronts", f_index, field, p_index),
                        f"'{pattern}' matches no output channel (outputs: {', '.join(outputs[:3]) or 'none'}{', ...' if len(outputs) > 3 else ''})",
                    )
        mine = (
            outputs
            if patterns is None
            else [o for o in outputs if any(fnmatch.fnmatchcase(o, p) for p in patterns)]
        )
        clashes: dict[int, list[str]] = {}
        for cid in mine:
            if cid in writer:
                clashes.setdefault(writer[cid], []).append(cid)
            else:
                writer[cid] = f_index
        for other, ids in clashes.items():
            more = f" and {len(ids) - 1} more" if len(ids) > 1 else ""
            issue(
                ("fronts", f_index, field)
                if getattr(front, field, None) is not None
                else ("fronts", f_index),
                f"output {ids[0]}{more} would be written by front '{front.name}' and by front "
                f"'{topology.fronts[other].name}'; one output has one writing front (narrow one "
                f"front's expose, or the Sparkplug front's writable list)",
            )
