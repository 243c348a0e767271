"""Command-line pieces every ``fieldgate`` command shares (``--set``, deprecated spellings,
one-line usage errors, seconds): below the commands, so core's commands and the plugins'
import them without importing :mod:`fieldgate.cli`."""

from __future__ import annotations

import argparse
import sys
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
    """``--set PATH=VALUE`` (repeatable), read with :func:`parse_overrides`: every command that loads a topology."""
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="PATH=VALUE",
        help=f"override a topology field before validation, e.g. {example}",
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
