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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import Field, ValidationError
from ruamel.yaml import YAML
from ruamel.yaml.error import MarkedYAMLError, YAMLError

from ..image import ChannelSpec
from .errors import ConfigIssue, TopologyError, data_loc, describe_pydantic_error, dotted, position, suggest
from .model import BackConfig, FrontConfig, GatewaySection, StrictModel


class _Root(StrictModel):
    gateway: GatewaySection
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
        modules = sum(len(b.modules) for b in self.backs)
        lines = [
            f"gateway {self.gateway.name}: {len(self.fronts)} front(s), {len(self.backs)} back(s), {modules} module(s), {len(self.channel_specs)} channel(s)",
            "  channels: " + ", ".join(f"{counts[k]} {k.value.upper()}" for k in Kind),
        ]
        for f in self.fronts:
            lines.append(f"  front {f.name} ({f.type})")
        for b in self.backs:
            n = sum(1 for s in self.channel_specs if s.source.back == b.name)
            lines.append(f"  back  {b.name} ({b.type}): {len(b.modules)} module(s), {n} channel(s)")
        return "\n".join(lines)


def _by_name(items: list, name: str, what: str):
    for item in items:
        if item.name == name:
            return item
    raise KeyError(f"no {what} named {name!r} (have: {', '.join(i.name for i in items)})")


def read_yaml(path: str | Path) -> Any:
    """Parse a YAML file keeping positions; syntax errors and duplicate keys become TopologyError."""
    file = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise TopologyError([ConfigIssue(file, None, None, "", f"cannot read file: {exc.strerror or exc}")]) from None
    yaml = YAML(typ="rt")
    try:
        return yaml.load(text)
    except MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        problem = (exc.problem or "invalid YAML").strip()
        if "duplicate key" in problem:
            start = exc.context_mark
            problem = f"{problem.split(' with value')[0]} in the mapping that starts on line {start.line + 1}; each key may appear once"
        line, col = (mark.line + 1, mark.column + 1) if mark else (None, None)
        raise TopologyError([ConfigIssue(file, line, col, "", f"YAML syntax: {problem}")]) from None
    except YAMLError as exc:
        raise TopologyError([ConfigIssue(file, None, None, "", f"YAML syntax: {exc}")]) from None


def apply_overrides(data: Any, overrides: dict[str, Any]) -> Any:
    """Set fields by dotted path before validation: ``fronts.can.interface`` or ``backs.0.port``.

    A list element is addressed by index or by its ``name``.
    """
    for dotted_path, value in overrides.items():
        parts = dotted_path.split(".")
        node = data
        for i, part in enumerate(parts):
            last = i == len(parts) - 1
            if isinstance(node, list):
                index = _list_index(node, part, dotted_path)
                if last:
                    node[index] = value
                else:
                    node = node[index]
            elif isinstance(node, dict):
                if last:
                    node[part] = value
                else:
                    node = node.setdefault(part, {})
            else:
                raise KeyError(f"override {dotted_path!r}: {'.'.join(parts[:i])} is not a mapping or list")
    return data


def _list_index(items: list, part: str, dotted_path: str) -> int:
    if part.isdigit():
        return int(part)
    for i, item in enumerate(items):
        if isinstance(item, dict) and item.get("name") == part:
            return i
    raise KeyError(f"override {dotted_path!r}: no list entry named {part!r}")


def load_topology(source: str | Path | dict, registry, overrides: dict[str, Any] | None = None) -> Topology:
    """Load and validate a topology from a YAML file or a dict. Raises TopologyError."""
    if isinstance(source, dict):
        data, file, base_dir = copy.deepcopy(source), "<dict>", Path.cwd()
    else:
        data, file, base_dir = read_yaml(source), str(source), Path(source).resolve().parent
    if overrides:
        try:
            data = apply_overrides(data, overrides)
        except KeyError as exc:
            raise TopologyError([ConfigIssue(file, None, None, "", str(exc.args[0]))]) from None
    return validate(data, registry, file, base_dir)


def validate(data: Any, registry, file: str = "<dict>", base_dir: Path | None = None) -> Topology:
    issues: list[ConfigIssue] = []
    if not isinstance(data, dict):
        raise TopologyError([ConfigIssue(file, 1, 1, "", "the file must be a mapping with keys gateway, fronts, backs")])
    try:
        root = _Root.model_validate(data)
    except ValidationError as exc:
        issues.extend(_issues_from(exc, _Root, data, (), file))
        raise TopologyError(_dedupe(issues)) from None

    fronts: list[FrontConfig] = []
    backs: list[BackConfig] = []
    for role, entries, out in (("front", root.fronts, fronts), ("back", root.backs, backs)):
        section = f"{role}s"
        for i, entry in enumerate(data[section]):
            base = (section, i)
            type_name = entry.get("type") if isinstance(entry, dict) else None
            if not isinstance(type_name, str):
                line, col = position(data, base)
                issues.append(ConfigIssue(file, line, col, dotted(base + ("type",)), f"required field is missing: the {role} type, one of: {', '.join(registry.type_names(role)) or '(none installed)'}"))
                continue
            ctype = registry.lookup(role, type_name)
            if ctype is None:
                line, col = position(data, base + ("type",))
                installed = ", ".join(registry.type_names(role)) or "none"
                hint = suggest(type_name, registry.type_names(role))
                issues.append(ConfigIssue(file, line, col, dotted(base + ("type",)), f"no installed plugin provides {role} type '{type_name}'{hint} (installed {role} types: {installed}); is the plugin installed?"))
                continue
            try:
                out.append(ctype.model.model_validate(dict(entry)))
            except ValidationError as exc:
                issues.extend(_issues_from(exc, ctype.model, data, base, file))
    if issues:
        raise TopologyError(_dedupe(issues))

    topology = Topology(root.gateway, fronts, backs, file, base_dir or Path.cwd())
    issues.extend(_cross_checks(topology, data, file))
    if issues:
        raise TopologyError(_dedupe(issues))
    return topology


def _issues_from(exc: ValidationError, model, data: Any, base: tuple, file: str) -> list[ConfigIssue]:
    out = []
    for err in exc.errors(include_url=False):
        raw_loc = tuple(err["loc"])
        full = base + data_loc(_at(data, base), raw_loc)
        line, col = position(data, full, key=err["type"] == "extra_forbidden")
        out.append(ConfigIssue(file, line, col, dotted(full), describe_pydantic_error(err, model, raw_loc)))
    return out


def _at(data: Any, loc: tuple) -> Any:
    for part in loc:
        data = data[part]
    return data


def _dedupe(issues: list[ConfigIssue]) -> list[ConfigIssue]:
    """Merge the several errors pydantic reports for one field of a union into one line."""
    merged: dict[tuple, ConfigIssue] = {}
    for issue in issues:
        key = (issue.file, issue.line, issue.column, issue.path)
        if key in merged:
            prev = merged[key]
            if issue.message not in prev.message:
                merged[key] = ConfigIssue(prev.file, prev.line, prev.column, prev.path, f"{prev.message}; or {issue.message}")
        else:
            merged[key] = issue
    return sorted(merged.values(), key=lambda i: (i.line or 0, i.column or 0, i.path))


def _cross_checks(topology: Topology, data: Any, file: str) -> list[ConfigIssue]:
    issues: list[ConfigIssue] = []

    def issue(loc: tuple, message: str) -> None:
        line, col = position(data, loc)
        issues.append(ConfigIssue(file, line, col, dotted(loc), message))

    seen: dict[str, tuple] = {}
    for section, items in (("fronts", topology.fronts), ("backs", topology.backs)):
        for i, item in enumerate(items):
            if item.name in seen:
                first = seen[item.name]
                issue((section, i, "name"), f"name '{item.name}' is already used by {dotted(first)}; names must be unique across fronts and backs")
            else:
                seen[item.name] = (section, i)

    for b_index, back in enumerate(topology.backs):
        addresses: dict[int, int] = {}
        for m_index, module in enumerate(back.modules):
            if module.address in addresses:
                issue(("backs", b_index, "modules", m_index, "address"), f"address {module.address} is already used by modules[{addresses[module.address]}] on this line")
            else:
                addresses[module.address] = m_index
        if issues:
            continue
        try:
            topology.channel_specs.extend(back.channel_specs())
        except ValueError as exc:
            issue(("backs", b_index), str(exc))

    if issues:
        return issues  # channel ids are incomplete: checking expose would only add noise
    ids = {s.id for s in topology.channel_specs}
    for f_index, front in enumerate(topology.fronts):
        for e_index, pattern in enumerate(front.expose or []):
            if not fnmatch.filter(ids, pattern):
                close = suggest(pattern, sorted(ids))
                issue(("fronts", f_index, "expose", e_index), f"'{pattern}' matches no channel{close or ''} (channel ids look like <back>/m<address>/<kind><index>, e.g. {next(iter(sorted(ids)), 'rs485/m1/di0')})")
    return issues
