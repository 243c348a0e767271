"""A SocketCAN interface under the gateway's control: bit timing, bus-off recovery, state.

What a CAN front needs of the kernel beyond sending and receiving frames (docs/can-link.md):

* :func:`read_link`: bit rate, sample point, restart-ms, listen-only, up/down, the controller
  state (error-active, error-warning, error-passive, bus-off, stopped) and its error counters;
* :func:`apply_settings`: the topology's ``bitrate`` (and sample point, restart-ms) applied at
  start where the interface differs: down, set, up; nothing when it already matches, a
  :class:`LinkError` naming why when it cannot (no CAP_NET_ADMIN, a rate the controller
  cannot do, a virtual interface);
* :func:`configure`, :func:`set_up`, :func:`restart`: the single steps (an LSS or DeviceNet
  bit-rate switch is :func:`apply_settings` with the new rate).

Changing an interface needs CAP_NET_ADMIN; reading it does not. Every call is blocking (a
few hundred microseconds; bringing an slcan interface up waits for its adapter): an async
caller runs it in a thread (``asyncio.to_thread``). :func:`plan` is the pure part.
"""

from __future__ import annotations

import errno
from dataclasses import dataclass, field

from .rtnetlink import LinkChange, RawLink, RouteSocket

CanLink = RawLink  # what read_link returns (fields: see rtnetlink.RawLink)
CAP = "CAP_NET_ADMIN"


class LinkError(Exception):
    """One line saying why the interface could not be read or changed."""

    def __init__(self, text: str, code: int = 0):
        super().__init__(text)
        self.errno = code


def _explain(name: str, doing: str, exc: OSError) -> LinkError:
    code = exc.errno or 0
    if code in (errno.EPERM, errno.EACCES):
        return LinkError(
            f"{name}: {doing} needs the capability {CAP} (run as root, or grant it: "
            "AmbientCapabilities=CAP_NET_ADMIN, docs/deploy.md)",
            code,
        )
    if code == errno.ENODEV:
        return LinkError(f"{name}: no such network interface", code)
    if code == errno.EOPNOTSUPP:
        return LinkError(f"{name}: {doing}: the interface's driver does not support it", code)
    if code == errno.EDOM:  # the kernel found no bit timing within tolerance for this clock
        return LinkError(f"{name}: {doing}: the controller cannot make it from its clock", code)
    if code == errno.EINVAL:
        return LinkError(
            f"{name}: {doing}: the controller refused the value (Invalid argument)", code
        )
    return LinkError(f"{name}: {doing}: {exc.strerror or exc}", code)


def _socket() -> RouteSocket:
    try:
        return RouteSocket()
    except OSError as exc:  # no AF_NETLINK (not Linux)
        raise LinkError(f"no rtnetlink here: {exc.strerror or exc}", exc.errno or 0) from exc


def read_link(name: str) -> CanLink:
    """The interface as the kernel reports it; LinkError when it does not exist."""
    with _socket() as nl:
        try:
            return nl.get(name)
        except OSError as exc:
            raise _explain(name, "reading the interface", exc) from exc


def _set(name: str, change: LinkChange, doing: str) -> None:
    with _socket() as nl:
        try:
            nl.set(nl.get(name).index, change)
        except OSError as exc:
            raise _explain(name, doing, exc) from exc


def set_up(name: str, up: bool) -> None:
    _set(name, LinkChange(up=up), "bringing the interface " + ("up" if up else "down"))


def configure(
    name: str,
    *,
    bitrate: int | None = None,
    sample_point: float | None = None,
    restart_ms: int | None = None,
    listen_only: bool | None = None,
) -> None:
    """Set what is given, on an interface that is down (the kernel refuses bit timing and
    restart-ms on a running one: EBUSY)."""
    change = LinkChange(bitrate, sample_point, restart_ms, listen_only)
    _set(name, change, describe(change))


def restart(name: str) -> str:
    """Restart a controller after bus-off. The kernel's restart where the driver has one
    (it refuses unless the controller is bus-off); a driver without it (slcan) is taken down
    and up, which resets it. Returns how it was done."""
    try:
        _set(name, LinkChange(restart=True), "restarting the controller")
        return "restart"
    except LinkError as exc:
        if exc.errno == errno.EBUSY:
            raise LinkError(f"{name}: not restarted: the controller is not bus-off") from exc
        if exc.errno == errno.EINVAL:  # the kernel's answer when it restarts by itself, or down
            link = read_link(name)
            why = (
                f"restart-ms is {link.restart_ms}: the kernel restarts it by itself after bus-off"
                if link.restart_ms
                else "the interface is down"
            )
            raise LinkError(f"{name}: not restarted: {why}", exc.errno) from exc
        if exc.errno != errno.EOPNOTSUPP:
            raise
    set_up(name, False)
    set_up(name, True)
    return "down/up"


def describe(change: LinkChange) -> str:
    parts = []
    if change.bitrate is not None:
        parts.append(f"bit rate {change.bitrate}")
    if change.sample_point is not None:
        parts.append(f"sample point {change.sample_point:.3f}")
    if change.restart_ms is not None:
        parts.append(f"restart-ms {change.restart_ms}")
    if change.listen_only is not None:
        parts.append("listen-only " + ("on" if change.listen_only else "off"))
    return "setting " + (", ".join(parts) or "nothing")


# -- applying a configuration ---------------------------------------------------------------
@dataclass(frozen=True)
class LinkSettings:
    """What the topology asks of the interface (None: leave the interface's own)."""

    bitrate: int
    sample_point: float | None = None
    restart_ms: int | None = None
    listen_only: bool = False


@dataclass
class Plan:
    """What :func:`apply_settings` will do: the change (None: nothing to do), the
    differences it found, a note (e.g. a virtual interface), or why it cannot."""

    change: LinkChange | None
    differences: list[str] = field(default_factory=list)
    note: str = ""
    impossible: str = ""


SAMPLE_POINT_TOLERANCE = 0.0015  # the kernel rounds the sample point to its time quanta


def plan(link: CanLink, wanted: LinkSettings) -> Plan:
    """Compare the interface with the settings (pure: no I/O)."""
    if link.kind in ("vcan", "vxcan"):
        return Plan(
            None,
            note=f"{link.name} is a virtual CAN interface ({link.kind}): it has no bit timing; "
            f"bit rate {wanted.bitrate} is taken as configured",
        )
    if link.kind != "can":
        return Plan(
            None,
            impossible=f"{link.name} is not a CAN controller (link kind {link.kind or 'none'!r})",
        )
    if link.bitrate_const and wanted.bitrate not in link.bitrate_const:
        rates = ", ".join(str(r) for r in link.bitrate_const)
        return Plan(
            None,
            impossible=f"{link.name} cannot run at {wanted.bitrate} bit/s (its rates: {rates})",
        )
    diffs: list[str] = []
    bitrate = sample_point = restart_ms = None
    listen_only = None
    sp_differs = (
        wanted.sample_point is not None
        and link.sample_point is not None
        and abs(link.sample_point - wanted.sample_point) > SAMPLE_POINT_TOLERANCE
    )
    if link.bitrate != wanted.bitrate or sp_differs:
        bitrate, sample_point = wanted.bitrate, wanted.sample_point
        diffs.append(f"bit rate {link.bitrate or 'unset'} -> {wanted.bitrate}")
        if sp_differs:
            diffs.append(f"sample point {link.sample_point} -> {wanted.sample_point}")
    if wanted.restart_ms is not None and link.restart_ms != wanted.restart_ms:
        restart_ms = wanted.restart_ms
        diffs.append(f"restart-ms {link.restart_ms} -> {wanted.restart_ms}")
    if link.listen_only is not None and link.listen_only != wanted.listen_only:
        listen_only = wanted.listen_only
        diffs.append("listen-only " + ("on" if wanted.listen_only else "off"))
    if wanted.listen_only and link.listen_only_supported is False:
        return Plan(None, impossible=f"{link.name}: the controller has no listen-only mode")
    if not diffs:
        return Plan(None)
    return Plan(LinkChange(bitrate, sample_point, restart_ms, listen_only), diffs)


@dataclass
class Applied:
    """What :func:`apply_settings` did, and the interface afterwards."""

    link: CanLink
    differences: list[str]
    note: str = ""

    @property
    def changed(self) -> bool:
        return bool(self.differences)


def apply_settings(name: str, wanted: LinkSettings) -> Applied:
    """Bring the interface to the settings: compare, and where it differs take it down, set
    what differs and bring it up again; an interface that matches is only brought up.
    Raises LinkError with one line when that cannot be done (the interface is left as the
    kernel has it)."""
    link = read_link(name)
    steps = plan(link, wanted)
    if steps.impossible:
        raise LinkError(steps.impossible)
    try:
        if steps.change is not None:
            if link.up:
                set_up(name, False)
            _set(name, steps.change, describe(steps.change))
        if steps.change is not None or not link.up:
            set_up(name, True)
    except LinkError as exc:
        if exc.errno in (errno.EPERM, errno.EACCES):
            wanted_text = "; ".join(steps.differences) or "bringing it up"
            raise LinkError(
                f"{name}: {wanted_text}: changing the interface needs the capability {CAP} "
                "(run as root, or grant it: AmbientCapabilities=CAP_NET_ADMIN, docs/deploy.md)",
                exc.errno,
            ) from exc
        raise
    return Applied(read_link(name), steps.differences, steps.note)
