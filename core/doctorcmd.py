"""``fieldgate doctor TOPOLOGY``: what the topology needs of this host, checked before ``run``.

One line per finding, each with its fix (docs/deploy.md, "Before the first start"):

* **CAN interfaces** of the SocketCAN fronts (read through ``fieldgate.can.link``, no change
  made): present, a CAN controller (or vcan), up, at the topology's bit rate, ``restart-ms``
  set (0: a bus-off is never recovered);
* **serial ports** of the serial backs: present, not held by another process, readable and
  writable by the service's user and groups (the unit's ``User=``, ``Group=``,
  ``SupplementaryGroups=``), a stable ``/dev/serial/by-id`` name for a ``/dev/ttyUSB*`` one;
* **listeners** (the fronts' ``listen`` and the status server's): the port free on its address,
  one below 1024 only with CAP_NET_BIND_SERVICE;
* **the systemd unit** (the installed one, else the shipped one, or ``--unit FILE``): the
  capabilities and address families those need (CAP_NET_ADMIN and AF_CAN for SocketCAN,
  CAP_SYS_NICE for a negative ``fieldbus_nice``);
* **CPUs**: ``fieldbus_cpus`` and ``north_cpus`` name CPUs this host offers, and leave the
  children at least one.

Exit code (README, "Exit codes"): 0 when nothing stops the gateway (notes and warnings
only), 1 when something will (a FAIL line; an invalid topology), 2 when the command line is
wrong. The checks read the host through :class:`Host`, which tests point at a tree of their
own.
"""

from __future__ import annotations

import argparse
import errno
import os
import re
import socket
import stat
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .exitcodes import ExitCode
from .plugin import Registry
from .topology import SerialBackConfig, Topology, TopologyError, load_topology
from .topology.model import split_listen

OK, NOTE, WARN, FAIL = "ok", "note", "warn", "FAIL"
INSTALLED_UNIT = "/etc/systemd/system/fieldgate@.service"
UNSTABLE = re.compile(r"^/dev/tty(USB|ACM)\d+$")


@dataclass(frozen=True)
class Finding:
    level: str
    subject: str
    text: str
    fix: str = ""

    def line(self) -> str:
        return f"{self.level:<4}  {self.subject}: {self.text}" + (
            f"; fix: {self.fix}" if self.fix else ""
        )


@dataclass
class Unit:
    """What the doctor reads of a systemd unit: its [Service] settings, each as a list."""

    path: str
    settings: dict[str, list[str]] = field(default_factory=dict)

    @classmethod
    def parse(cls, path: str, text: str) -> Unit:
        unit = cls(path)
        section = ""
        for raw in text.splitlines():
            line = raw.strip()
            if not line or line.startswith(("#", ";")):
                continue
            if line.startswith("["):
                section = line
                continue
            key, sep, value = line.partition("=")
            if sep and section == "[Service]":
                words = value.split()
                if not words:  # an empty assignment resets the list
                    unit.settings[key.strip()] = []
                else:
                    unit.settings.setdefault(key.strip(), []).extend(words)
        return unit

    def get(self, key: str) -> list[str]:
        return self.settings.get(key, [])

    @property
    def user(self) -> str:
        return (self.get("User") or ["root"])[-1]

    def has_capability(self, cap: str) -> bool:
        if self.user == "root" and "AmbientCapabilities" not in self.settings:
            return "CapabilityBoundingSet" not in self.settings or cap in self.get(
                "CapabilityBoundingSet"
            )
        return cap in self.get("AmbientCapabilities") and (
            "CapabilityBoundingSet" not in self.settings or cap in self.get("CapabilityBoundingSet")
        )

    def allows_family(self, family: str) -> bool:
        families = self.get("RestrictAddressFamilies")
        return not families or family in families


class Host:
    """The host as the checks see it: ``root`` prefixes /dev, /proc and /sys (a test's tree),
    the user database and the CAN link reader can be replaced too."""

    def __init__(
        self,
        root: str = "/",
        read_link: Callable[[str], Any] | None = None,
        users: Callable[[str], tuple[int, int] | None] | None = None,
        groups: Callable[[str], int | None] | None = None,
        group_name: Callable[[int], str] | None = None,
        cpus: Callable[[], set[int]] | None = None,
    ):
        self.root = Path(root)
        self._cpus = cpus
        self._read_link = read_link
        self._users = users
        self._groups = groups
        self._group_name = group_name

    def path(self, absolute: str) -> Path:
        return self.root / absolute.lstrip("/")

    def read_link(self, name: str) -> Any:
        if self._read_link is not None:
            return self._read_link(name)
        from .can.link import read_link

        return read_link(name)

    def cpus(self) -> set[int]:
        """The CPUs the gateway may run on (this process's affinity, as the service inherits)."""
        return self._cpus() if self._cpus is not None else set(os.sched_getaffinity(0))

    def user(self, name: str) -> tuple[int, int] | None:
        """(uid, primary gid) of a user, None when there is no such user."""
        if self._users is not None:
            return self._users(name)
        import pwd

        try:
            entry = pwd.getpwnam(name)
        except KeyError:
            return None
        return entry.pw_uid, entry.pw_gid

    def gid(self, name: str) -> int | None:
        if self._groups is not None:
            return self._groups(name)
        import grp

        try:
            return grp.getgrnam(name).gr_gid
        except KeyError:
            return None

    def group(self, gid: int) -> str:
        if self._group_name is not None:
            return self._group_name(gid)
        import grp

        try:
            return grp.getgrgid(gid).gr_name
        except KeyError:
            return str(gid)

    def holders(self, target: Path) -> list[str]:
        """``pid (name)`` of every process with ``target`` open (that /proc lets us see)."""
        out = []
        proc = self.path("/proc")
        try:
            pids = [p for p in proc.iterdir() if p.name.isdigit()]
        except OSError:
            return []
        for pid in pids:
            try:
                fds = list((pid / "fd").iterdir())
            except OSError:
                continue
            for fd in fds:
                try:
                    if os.readlink(fd) == str(target):
                        comm = (
                            (pid / "comm").read_text().strip() if (pid / "comm").exists() else "?"
                        )
                        out.append(f"pid {pid.name} ({comm})")
                        break
                except OSError:
                    continue
        return out

    def socket_holders(self, port: int) -> list[str]:
        """Who listens on a TCP port (``/proc/net/tcp``, ``tcp6``, then the sockets' owners)."""
        inodes = set()
        for table in ("tcp", "tcp6"):
            try:
                lines = self.path(f"/proc/net/{table}").read_text().splitlines()[1:]
            except OSError:
                continue
            for line in lines:
                fields = line.split()
                if (
                    len(fields) > 9
                    and fields[3] == "0A"
                    and int(fields[1].split(":")[1], 16) == port
                ):
                    inodes.add(fields[9])
        return [h for inode in sorted(inodes) for h in self.holders(Path(f"socket:[{inode}]"))]


def check(
    topology: Topology,
    host: Host,
    unit: Unit | None,
    bind: Callable[[str, int], None] | None = None,
) -> list[Finding]:
    """Every finding for ``topology`` on ``host`` (the order: CAN, serial, listeners, unit)."""
    findings: list[Finding] = []
    findings += _can(topology, host, unit)
    findings += _serial(topology, host, unit)
    findings += _listeners(topology, host, unit, bind or _try_bind)
    findings += _unit(topology, unit)
    findings += _cpus(topology, host)
    return findings


# -- CAN ----------------------------------------------------------------------------------------
def _socketcan(topology: Topology) -> list[Any]:
    """The fronts on a SocketCAN interface (a CAN front's ``interface``, ``channel``, ``bitrate``:
    ``fieldgate.can.front.CanBusConfig``)."""
    return [f for f in topology.fronts if getattr(f, "interface", None) == "socketcan"]


def _can(topology: Topology, host: Host, unit: Unit | None) -> list[Finding]:
    out: list[Finding] = []
    for front in _socketcan(topology):
        name: str = getattr(front, "channel", None) or "can0"
        bitrate: int | None = getattr(front, "bitrate", None)
        subject = f"front {front.name}: {name}"
        setup = f"ip link set {name} type can bitrate {bitrate or 125000} restart-ms 100"
        try:
            link = host.read_link(name)
        except Exception as exc:  # LinkError: one line, e.g. no such network interface
            text = str(exc).removeprefix(f"{name}: ")
            out.append(
                Finding(
                    FAIL,
                    subject,
                    text,
                    f"plug the adapter or load its driver (ip -details link show {name}), then "
                    f"{setup}; ip link set {name} up",
                )
            )
            continue
        if link.kind in ("vcan", "vxcan"):
            out.append(
                Finding(
                    OK if link.up else FAIL,
                    subject,
                    f"virtual CAN ({link.kind}), " + ("up" if link.up else "down"),
                    "" if link.up else f"ip link set {name} up",
                )
            )
            continue
        if link.kind != "can":
            out.append(
                Finding(
                    FAIL,
                    subject,
                    f"not a CAN interface (link kind {link.kind or 'none'})",
                    "name the CAN interface in the front's channel",
                )
            )
            continue
        if bitrate is not None and link.bitrate != bitrate:
            can_set = unit is not None and unit.has_capability("CAP_NET_ADMIN")
            out.append(
                Finding(
                    WARN if can_set else FAIL,
                    subject,
                    f"runs at {link.bitrate or 'no'} bit/s, the topology says {bitrate}"
                    + (
                        " (fieldgate sets it at start: the unit grants CAP_NET_ADMIN)"
                        if can_set
                        else ""
                    ),
                    f"ip link set {name} down; {setup}; ip link set {name} up "
                    f"(or systemd-networkd: [CAN] BitRate={bitrate})",
                )
            )
        if not link.up:
            out.append(
                Finding(FAIL, subject, "the interface is down", f"{setup}; ip link set {name} up")
            )
        if not link.restart_ms:
            out.append(
                Finding(
                    FAIL,
                    subject,
                    "restart-ms is 0: after a bus-off the controller stays off the bus until someone restarts it",
                    f"ip link set {name} down; ip link set {name} type can restart-ms 100; ip link "
                    f"set {name} up (systemd-networkd: [CAN] RestartSec=100ms)",
                )
            )
        if link.up and (bitrate is None or link.bitrate == bitrate) and link.restart_ms:
            out.append(
                Finding(
                    OK,
                    subject,
                    f"up at {link.bitrate} bit/s, restart-ms {link.restart_ms}, state {link.state or '?'}",
                )
            )
    return out


# -- serial ports ---------------------------------------------------------------------------
def _service_ids(host: Host, unit: Unit | None) -> tuple[str, int | None, set[int], list[str]]:
    """(user, uid, gids, the group names) the service runs with."""
    if unit is None:
        import getpass

        name = getpass.getuser()
    else:
        name = unit.user
    found = host.user(name)
    uid, gids, names = (found[0], {found[1]}, []) if found else (None, set(), [])
    if unit is not None:
        for group_name in [*unit.get("Group"), *unit.get("SupplementaryGroups")]:
            names.append(group_name)
            gid = host.gid(group_name)
            if gid is not None:
                gids.add(gid)
    elif found is not None:
        gids |= set(os.getgroups())
    return name, uid, gids, names


def _serial(topology: Topology, host: Host, unit: Unit | None) -> list[Finding]:
    out: list[Finding] = []
    user, uid, gids, group_names = _service_ids(host, unit)
    for back in topology.backs:
        if not isinstance(back, SerialBackConfig):
            continue
        port, subject = back.port, f"back {back.name}: {back.port}"
        if "://" in port:
            out.append(Finding(NOTE, subject, "a pyserial URL (a serial server): not checked here"))
            continue
        path = host.path(port)
        if not path.exists():
            by_id = _by_id_names(host)
            out.append(
                Finding(
                    FAIL,
                    subject,
                    "no such device",
                    "plug the adapter (dmesg names it); "
                    + (
                        f"serial ports here: {', '.join(by_id)}"
                        if by_id
                        else "no /dev/serial/by-id names here"
                    ),
                )
            )
            continue
        st = path.stat()
        if not (stat.S_ISCHR(st.st_mode) or (host.root != Path("/") and stat.S_ISREG(st.st_mode))):
            out.append(Finding(FAIL, subject, "not a character device", "name the serial device"))
            continue
        problems = False
        if uid != 0 and not _may_use(st, uid, gids):
            problems = True
            group = host.group(st.st_gid)
            out.append(
                Finding(
                    FAIL,
                    subject,
                    f"owned by group {group}, mode {stat.filemode(st.st_mode)}: user {user} "
                    f"(groups {', '.join(group_names) or '-'}) cannot open it",
                    f"SupplementaryGroups={group} in the unit (or usermod -aG {group} {user})",
                )
            )
        holders = host.holders(Path(os.path.realpath(path)) if host.root == Path("/") else path)
        if holders:
            problems = True
            out.append(
                Finding(
                    FAIL,
                    subject,
                    f"busy: held by {', '.join(holders)}",
                    "stop it (ModemManager: systemctl disable --now ModemManager; another gateway: "
                    "systemctl stop fieldgate@...) or use another port",
                )
            )
        if UNSTABLE.match(port):
            stable = [n for n in _by_id_names(host) if _same_device(host, n, path)]
            out.append(
                Finding(
                    WARN,
                    subject,
                    "a name the kernel hands out in plug order: after a reboot or a replug it may be another adapter",
                    f"port: {stable[0]}"
                    if stable
                    else "a udev rule with a SYMLINK for this adapter (no /dev/serial/by-id name for it here)",
                )
            )
        elif not problems:
            out.append(Finding(OK, subject, "present, free, usable by " + user))
    return out


def _by_id_names(host: Host) -> list[str]:
    folder = host.path("/dev/serial/by-id")
    try:
        return sorted(f"/dev/serial/by-id/{p.name}" for p in folder.iterdir())
    except OSError:
        return []


def _same_device(host: Host, name: str, path: Path) -> bool:
    link = host.path(name)
    try:
        target = os.readlink(link)
    except OSError:
        return False
    resolved = (link.parent / target).resolve() if not os.path.isabs(target) else host.path(target)
    return resolved == path.resolve()


def _may_use(st: os.stat_result, uid: int | None, gids: set[int]) -> bool:
    mode = st.st_mode
    if uid is not None and st.st_uid == uid:
        return mode & 0o600 == 0o600
    if st.st_gid in gids:
        return mode & 0o060 == 0o060
    return mode & 0o006 == 0o006


# -- listeners ------------------------------------------------------------------------------
def _listens(topology: Topology) -> list[tuple[str, str]]:
    out = [
        (f"front {f.name}", str(getattr(f, "listen", "")))
        for f in topology.fronts
        if isinstance(getattr(f, "listen", None), str)
    ]
    if topology.gateway.http is not None:
        out.append(("http", topology.gateway.http.listen))
    return out


def _try_bind(host: str, port: int) -> None:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the servers bind
        s.bind((host, port))


def _listeners(
    topology: Topology, host: Host, unit: Unit | None, bind: Callable[[str, int], None]
) -> list[Finding]:
    out = []
    for who, listen in _listens(topology):
        address, port = split_listen(listen)
        subject = f"{who}: {listen}"
        if port == 0:
            out.append(Finding(NOTE, subject, "port 0: any free port"))
            continue
        if (
            port < 1024
            and unit is not None
            and unit.user != "root"
            and not unit.has_capability("CAP_NET_BIND_SERVICE")
        ):
            out.append(
                Finding(
                    FAIL,
                    subject,
                    f"port {port} is below 1024: user {unit.user} needs CAP_NET_BIND_SERVICE",
                    "AmbientCapabilities=CAP_NET_BIND_SERVICE (and in CapabilityBoundingSet) in a "
                    "drop-in, or a port from 1024 up",
                )
            )
        try:
            bind(address or "0.0.0.0", port)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                holders = host.socket_holders(port)
                out.append(
                    Finding(
                        FAIL,
                        subject,
                        "in use" + (f" by {', '.join(holders)}" if holders else ""),
                        "stop what listens there, or give this listener another port",
                    )
                )
            elif exc.errno == errno.EADDRNOTAVAIL:
                out.append(
                    Finding(
                        FAIL,
                        subject,
                        f"{address} is no address of this host",
                        "listen on one of its addresses (ip -brief address)",
                    )
                )
            elif exc.errno in (errno.EACCES, errno.EPERM):
                continue  # below 1024 as an ordinary user: the unit's capability decides (above)
            else:
                out.append(Finding(FAIL, subject, exc.strerror or str(exc)))
            continue
        if not any(f.subject == subject for f in out):
            out.append(Finding(OK, subject, "free"))
    return out


# -- the unit -------------------------------------------------------------------------------
def _unit(topology: Topology, unit: Unit | None) -> list[Finding]:
    if unit is None:
        return [Finding(NOTE, "unit", "no unit checked (--unit FILE; docs/deploy.md)")]
    out = []
    subject = f"unit {unit.path}"
    socketcan = [f.name for f in _socketcan(topology)]
    if socketcan and not unit.allows_family("AF_CAN"):
        out.append(
            Finding(
                FAIL,
                subject,
                f"RestrictAddressFamilies= leaves out AF_CAN: front {socketcan[0]} cannot open its bus",
                "add AF_CAN to RestrictAddressFamilies=",
            )
        )
    if socketcan and not unit.has_capability("CAP_NET_ADMIN"):
        out.append(
            Finding(
                WARN,
                subject,
                "no CAP_NET_ADMIN: fieldgate cannot set the bit rate or restart after bus-off; the interface must be configured outside it",
                "AmbientCapabilities=CAP_NET_ADMIN (the shipped unit's), or systemd-networkd's [CAN] section",
            )
        )
    if socketcan and not unit.allows_family("AF_NETLINK"):
        out.append(
            Finding(
                WARN,
                subject,
                "RestrictAddressFamilies= leaves out AF_NETLINK: the CAN link cannot be read or set",
                "add AF_NETLINK",
            )
        )
    nice = topology.gateway.isolation.fieldbus_nice
    if (
        nice is not None
        and nice < 0
        and not unit.has_capability("CAP_SYS_NICE")
        and not unit.get("Nice")
    ):
        out.append(
            Finding(
                WARN,
                subject,
                f"fieldbus_nice {nice} needs CAP_SYS_NICE; without it the fieldbus process stays at 0",
                f"Nice={nice} in a drop-in (systemd sets it before the start), or AmbientCapabilities=CAP_SYS_NICE",
            )
        )
    if not out:
        out.append(
            Finding(
                OK,
                subject,
                f"user {unit.user}, capabilities {' '.join(unit.get('AmbientCapabilities')) or '-'}",
            )
        )
    return out


# -- CPUs -------------------------------------------------------------------------------------
def _cpus(topology: Topology, host: Host) -> list[Finding]:
    """``fieldbus_cpus`` and ``north_cpus`` against the CPUs this host offers."""
    iso = topology.gateway.isolation
    if not iso.fieldbus_cpus and not iso.north_cpus:
        return []
    from .isolation.cpus import cpu_list_text

    have = host.cpus()
    shown = cpu_list_text(have)
    out = []
    for key, wanted in (("fieldbus_cpus", iso.fieldbus_cpus), ("north_cpus", iso.north_cpus)):
        missing = sorted(set(wanted or ()) - have)
        if missing:
            out.append(
                Finding(
                    WARN,
                    "cpus",
                    f"{key}: CPU {cpu_list_text(missing)} not on this host (it offers {shown}); "
                    "the process runs unpinned",
                    f"name CPUs of {shown}",
                )
            )
    if not out and iso.fieldbus_cpus and not iso.north_cpus and have <= set(iso.fieldbus_cpus):
        out.append(
            Finding(
                WARN,
                "cpus",
                f"fieldbus_cpus takes every CPU ({shown}): the children share them",
                "leave at least one CPU out of fieldbus_cpus",
            )
        )
    return out or [
        Finding(
            OK,
            "cpus",
            f"fieldbus {iso.fieldbus_cpus or '-'}, children {iso.north_cpus or 'the others'}",
        )
    ]


# -- the command ------------------------------------------------------------------------------
def configure(parser: argparse.ArgumentParser) -> None:
    from .cliargs import add_overrides_argument

    parser.add_argument("file", help="the topology")
    add_overrides_argument(parser)
    parser.add_argument(
        "--unit",
        metavar="FILE",
        help=f"the systemd unit the gateway will run under (default: {INSTALLED_UNIT} when "
        "installed, else the shipped one: fieldgate service-unit)",
    )


def load_unit(path: str | None) -> Unit:
    if path is not None:
        return Unit.parse(path, Path(path).read_text())
    if Path(INSTALLED_UNIT).is_file():
        return Unit.parse(INSTALLED_UNIT, Path(INSTALLED_UNIT).read_text())
    from .unitcmd import unit_text

    return Unit.parse("(shipped) fieldgate@.service", unit_text())


def run(args: argparse.Namespace, registry: Registry, host: Host | None = None) -> int:
    from .cliargs import overrides_of

    try:
        topology = load_topology(args.file, registry, overrides_of(args, args.file))
    except TopologyError as exc:
        for issue in exc.issues:
            print(issue, file=sys.stderr)
        print(f"{args.file}: {len(exc.issues)} error(s): fix the topology first", file=sys.stderr)
        return ExitCode.FAILED
    try:
        unit = load_unit(args.unit)
    except OSError as exc:
        print(f"fieldgate doctor: --unit {args.unit}: {exc.strerror or exc}", file=sys.stderr)
        return ExitCode.CANNOT_RUN
    findings = check(topology, host or Host(), unit)
    for finding in findings:
        print(finding.line())
    failed = sum(1 for f in findings if f.level == FAIL)
    warned = sum(1 for f in findings if f.level == WARN)
    print(
        f"{args.file}: {failed} problem(s) that stop the gateway, {warned} warning(s)"
        if failed or warned
        else f"{args.file}: this host has what the topology needs"
    )
    return ExitCode.FAILED if failed else ExitCode.OK
