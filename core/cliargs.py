"""Command-line pieces every ``fieldgate`` command shares (``--set``, deprecated spellings,
one-line usage errors, seconds): below the commands, so core's commands and the plugins'
import them without importing :mod:`fieldgate.cli`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

from .exitcodes import ExitCode
from .topology import TopologyError

if TYPE_CHECKING:  # ruamel.yaml is imported when --set is used, not at every start
    from ruamel.yaml import YAML


def invalid_topology(exc: TopologyError) -> int:
    """Every error of a topology, one line each, on standard error; the exit code (1)."""
    for issue in exc.issues:
        print(issue, file=sys.stderr)
    return ExitCode.FAILED


def usage_error(message: str) -> NoReturn:
    """A wrong command line found after argparse: one line, exit 2 (as argparse's own)."""
    print(f"fieldgate: {message}", file=sys.stderr)
    raise SystemExit(ExitCode.CANNOT_RUN)


def deprecated(old: str, new: str) -> None:
    """The one-line note an old spelling prints (it keeps working for one more release)."""
    print(
        f"fieldgate: '{old}' is deprecated and goes away in the next release; use '{new}'",
        file=sys.stderr,
    )


def deprecated_alias(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup, old: str, new: str, **kwargs: Any
) -> None:
    """``old``, a former name of option ``new``: still accepted (with the note), not in the help."""

    class Alias(argparse.Action):
        def __call__(
            self,
            parser: argparse.ArgumentParser,
            namespace: argparse.Namespace,
            values: Any,
            option_string: str | None = None,
        ) -> None:
            deprecated(old, new)
            setattr(namespace, self.dest, values)

    parser.add_argument(
        old,
        dest=new.lstrip("-").replace("-", "_"),
        action=Alias,
        default=argparse.SUPPRESS,
        help=argparse.SUPPRESS,
        **kwargs,
    )


def add_overrides_argument(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup,
    example: str = "fronts.can.interface=virtual",
) -> None:
    """``--set PATH=VALUE`` and ``--scan-file [BACK=]FILE`` (repeatable), read with
    :func:`overrides_of`: every command that loads a topology."""
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="PATH=VALUE",
        help=f"override a topology field before validation, e.g. {example}",
    )
    parser.add_argument(
        "--scan-file",
        action="append",
        default=[],
        metavar="[BACK=]FILE",
        help="a scan file for a back that finds its modules at start (DCON modules: auto): "
        "sets backs.BACK.scan.file; BACK may be left out when the topology has one back",
    )


def overrides_of(args: argparse.Namespace, source: str | Path) -> dict[str, Any]:
    """``--set`` and ``--scan-file`` of a command that loads the topology ``source``."""
    overrides = parse_overrides(args.set)
    for item in getattr(args, "scan_file", None) or []:
        back, sep, file = item.rpartition("=")
        if not sep:
            back = _only_back(source, item)
        if not back or not file:
            usage_error(f"--scan-file expects [BACK=]FILE, got {item!r}")
        overrides[f"backs.{back}.scan.file"] = str(Path(file).resolve())
    return overrides


def _only_back(source: str | Path, item: str) -> str:
    from .topology.loader import read_yaml

    try:
        data = read_yaml(source)
    except TopologyError:
        return "0"  # the topology's own error is reported when it is loaded
    backs = data.get("backs") if isinstance(data, dict) else None
    names = [b.get("name") for b in backs if isinstance(b, dict)] if isinstance(backs, list) else []
    if len(names) == 1 and isinstance(names[0], str):
        return names[0]
    usage_error(
        f"--scan-file {item}: the topology has {len(names)} backs; name one: "
        f"--scan-file {names[0] if names and isinstance(names[0], str) else 'BACK'}={item}"
    )


def parse_overrides(items: list[str]) -> dict[str, Any]:
    """``--set fronts.can.interface=virtual`` pairs; values are parsed as YAML scalars."""
    from ruamel.yaml import YAML

    yaml = YAML(typ="safe")
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            usage_error(f"--set expects PATH=VALUE, got {item!r}")
        out[key] = _scalar(yaml, value)
    return out


def _scalar(yaml: YAML, text: str) -> Any:
    """A YAML value; text that only looks like a mapping (``a: b``) stays a string."""
    try:
        value = yaml.load(text) if text else ""
    except Exception:
        return text
    if isinstance(value, (dict, list)) and not text.lstrip().startswith(("{", "[")):
        return text
    return value


def seconds(text: str) -> float:
    """An argparse type: a number of seconds, 0 or more."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not value >= 0:  # also NaN
        raise argparse.ArgumentTypeError(f"expected 0 or more seconds, got {text!r}")
    return value
