"""The SocketCAN guests `.ci/socketcan/run` can boot, and what it knows of the host.

Each backend says whether it can run here (installing what it needs when asked), what a boot
needs built first, and the command line that boots it. docs/socketcan.md explains the order
and the reasons.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent
NAME = ".ci/socketcan/run"
BACKENDS = ("uml", "uml-noxstate", "kvm", "qemu")

# In the uml-noxstate guest: glibc and OpenSSL keep off AVX (its state is not preserved there).
GLIBC_SSE_ONLY = (
    "glibc.cpu.hwcaps=-AVX512F,-AVX512VL,-AVX512BW,-AVX512DQ,-AVX512CD,-AVX2,-AVX,-FMA,-F16C,"
    "-BMI1,-BMI2,-AVX_Fast_Unaligned_Load,-ERMS,-FSRM"
)
# OpenSSL's capability vector: clear AVX (CPUID.1:ECX bit 28) in the first word, and AVX2,
# AVX-512 (F, DQ, IFMA, CD, BW, VL, VBMI), VAES and VPCLMULQDQ in the second.
OPENSSL_SSE_ONLY = "~0x1000000000000000:~0x00000602D0230020"
UML_CAN_MODULES = (
    "kernel/net/can/can.ko",
    "kernel/net/can/can-raw.ko",
    "kernel/net/can/can-bcm.ko",
    "kernel/drivers/net/can/dev/can-dev.ko",
    "kernel/drivers/net/can/vcan.ko",
)
QEMU_PACKAGES = (
    "qemu-system-x86",
    "linux-image-amd64",
    "busybox-static",
    "cpio",
    "kmod",
    "iproute2",
)
UML_PACKAGES = ("user-mode-linux", "kmod", "iproute2")
# Emulated CAN controllers (`--can-controllers`): QEMU device models on one shared QEMU
# can-bus, each with the guest kernel module that drives it. The distribution kernel of this
# host (Debian 12, 6.1) has the SJA1000 family (kvaser_pci) but not ctucanfd.
CONTROLLER_DRIVERS = {
    "kvaser_pci": "kvaser_pci",
    "pcm3680_pci": "plx_pci",
    "ctucan_pci": "ctucanfd_pci",
}
CONTROLLER_COUNT = 2


def controller_model() -> str | None:
    """The emulated controller asked for (FIELDGATE_SOCKETCAN_CONTROLLERS), or None."""
    model = os.environ.get("FIELDGATE_SOCKETCAN_CONTROLLERS", "").strip()
    return model or None


def say(text: str) -> None:
    print(f"{NAME}: {text}", file=sys.stderr, flush=True)


# -- host facts ---------------------------------------------------------------------------------
def as_root(argv: list[str]) -> list[str]:
    if os.geteuid() == 0:
        return argv
    if shutil.which("sudo"):
        return ["sudo", "-n", *argv]
    raise RuntimeError("needs root or password-less sudo to install packages")


def apt_install(packages: tuple[str, ...] | list[str], why: str) -> str | None:
    """Install with apt-get (apt-get update only if the first attempt fails); None or the reason."""
    missing = [
        p
        for p in packages
        if subprocess.run(
            ["dpkg-query", "-W", "-f=${Status}", p], capture_output=True, text=True
        ).stdout
        != "install ok installed"
    ]
    if not missing:
        return None
    say(f"installing {' '.join(missing)} ({why})")
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    try:
        install = as_root(["apt-get", "install", "-y", "-q", "--no-install-recommends", *missing])
        update = as_root(["apt-get", "update", "-q"])
    except RuntimeError as exc:
        return str(exc)
    for attempt in (install, update, install):
        done = subprocess.run(attempt, stdout=sys.stderr, stderr=sys.stderr, env=env)
        if done.returncode == 0 and attempt is install:
            return None
    return f"apt-get could not install {' '.join(missing)}"


def cpu_flags() -> set[str]:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags"):
                return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def host_fingerprint(extra: str = "") -> str:
    """What a remembered verdict depends on: the host's kernel and CPU, the guest kernel
    (``extra``) and the runner's own files."""
    runner = b"".join(
        (HERE / name).read_bytes()
        for name in (
            "run",
            "socketcan_backends.py",
            "socketcan_guest.py",
            "guest-init.sh",
            "noxstate.c",
            "vector-guard.c",
        )
        if (HERE / name).exists()
    )
    facts = [os.uname().release, " ".join(sorted(cpu_flags())), extra]
    return hashlib.sha256("\n".join(facts).encode() + runner).hexdigest()[:16]


def file_identity(path: str | None) -> str:
    if not path:
        return ""
    real = os.path.realpath(path)
    try:
        stat = os.stat(real)
    except OSError:
        return real
    return f"{real}:{stat.st_size}:{int(stat.st_mtime)}"


class Cache:
    """The cache directory: built helpers, the QEMU initramfs, and the verdicts of backends
    that could not boot on this host."""

    def __init__(self) -> None:
        self.dir = Path(os.environ.get("FIELDGATE_SOCKETCAN_CACHE", "/var/tmp/fieldgate-socketcan"))
        self.dir.mkdir(parents=True, exist_ok=True)
        self.verdicts_file = self.dir / "verdicts.json"

    def _load(self) -> dict[str, dict[str, str]]:
        try:
            return json.loads(self.verdicts_file.read_text())
        except (OSError, ValueError):
            return {}

    def failure(self, backend: Backend) -> str | None:
        entry = self._load().get(backend.name)
        if entry and entry.get("fingerprint") == backend.fingerprint():
            return entry.get("reason")
        return None

    def remember_failure(self, backend: Backend, reason: str) -> None:
        verdicts = self._load()
        verdicts[backend.name] = {"fingerprint": backend.fingerprint(), "reason": reason}
        tmp = self.verdicts_file.with_suffix(".tmp")
        tmp.write_text(json.dumps(verdicts, indent=1))
        tmp.replace(self.verdicts_file)

    def forget(self) -> None:
        self.verdicts_file.unlink(missing_ok=True)

    def build(self, source: Path, output: str, *flags: str) -> Path:
        """A helper compiled from .ci/socketcan at first use (again when its source changes)."""
        digest = hashlib.sha256(source.read_bytes()).hexdigest()[:12]
        target = self.dir / f"{output}-{digest}"
        if not target.exists():
            if shutil.which("gcc") is None:
                reason = apt_install(["gcc", "libc6-dev"], f"to build {source.name}")
                if reason:
                    raise RuntimeError(reason)
            tmp = target.with_name(target.name + f".{os.getpid()}")
            done = subprocess.run(
                ["gcc", "-O2", *flags, "-o", str(tmp), str(source), *LINK.get(output, ())],
                capture_output=True,
                text=True,
            )
            if done.returncode != 0:
                raise RuntimeError(
                    f"gcc could not build {source.name}: {done.stderr.strip()[-400:]}"
                )
            tmp.replace(target)
        return target


LINK = {"noxstate.so": ("-ldl",), "vector-guard": ("-pthread",)}


# -- backends -----------------------------------------------------------------------------------
class Backend:
    name = ""
    what = ""
    default_mem = "1024M"
    native = True

    def __init__(self, cache: Cache) -> None:
        self.cache = cache

    def fingerprint(self) -> str:
        return host_fingerprint()

    def unavailable(self, install: bool) -> str | None:
        """Why this backend cannot be tried here (None: it can), installing what it needs
        first when ``install``."""
        raise NotImplementedError

    def prepare(self) -> None:
        """Build what a boot needs (helpers, an initramfs); raises RuntimeError."""

    def guest_settings(self, work: Path) -> dict[str, str]:
        return {}

    def host_env(self) -> dict[str, str]:
        return {}

    def argv(self, work: Path, mem: str) -> list[str]:
        raise NotImplementedError


class Uml(Backend):
    name = "uml"
    what = "User-Mode Linux"

    def kernel(self) -> str | None:
        return shutil.which("linux.uml")

    def fingerprint(self) -> str:
        return host_fingerprint(file_identity(self.kernel()))

    def unavailable(self, install: bool) -> str | None:
        if os.uname().machine != "x86_64":
            return f"User-Mode Linux is installed here for x86_64 only (this host: {os.uname().machine})"
        if install:
            reason = apt_install(UML_PACKAGES, "User-Mode Linux")
            if reason:
                return reason
        if controller_model():
            return (
                "User-Mode Linux has no PCI bus: emulated CAN controllers need QEMU (kvm or qemu)"
            )
        if self.kernel() is None:
            return "linux.uml is not installed (package user-mode-linux)"
        if self.module_dir() is None:
            return "no kernel modules under /usr/lib/uml/modules"
        return None

    def module_dir(self) -> Path | None:
        dirs = sorted(Path("/usr/lib/uml/modules").glob("*/"))
        return dirs[0] if dirs else None

    def guest_settings(self, work: Path) -> dict[str, str]:
        moddir = self.module_dir()
        assert moddir is not None
        return {
            "SOCKETCAN_INSMOD": " ".join(str(moddir / m) for m in UML_CAN_MODULES),
            "SOCKETCAN_INSMOD_OPTIONAL": str(moddir / "kernel/drivers/net/can/slcan/slcan.ko"),
        }

    def argv(self, work: Path, mem: str) -> list[str]:
        kernel = self.kernel()
        assert kernel is not None
        if os.environ.get("FIELDGATE_SOCKETCAN_TEST_BREAK") == self.name:
            # for the runner's own tests: fail at boot as UML does on hosts with AMX
            return [
                "sh",
                "-c",
                "echo 'userspace - ptrace set fp regs failed, errno = 14'; "
                "echo 'Kernel panic - not syncing: Attempted to kill init!'; exit 1",
            ]
        return [
            kernel,
            f"mem={mem}",
            "root=/dev/root",
            "rootfstype=hostfs",
            "rootflags=/",
            "rw",
            f"init={work}/init",
            "quiet",
            "loglevel=1",
            "con=null",
            "con0=fd:0,fd:1",
        ]


class UmlNoXstate(Uml):
    name = "uml-noxstate"
    what = (
        "User-Mode Linux without XSTATE (LD_PRELOAD shim, SSE-only glibc and OpenSSL, vector guard)"
    )

    def unavailable(self, install: bool) -> str | None:
        reason = super().unavailable(install)
        if reason:
            return reason
        if "avx" not in cpu_flags():
            return "this CPU has no AVX: plain uml keeps its whole vector state"
        return None

    def prepare(self) -> None:
        self.shim = self.cache.build(HERE / "noxstate.c", "noxstate.so", "-shared", "-fPIC")

    def host_env(self) -> dict[str, str]:
        return {"LD_PRELOAD": str(self.shim)}

    def sse_only(self) -> bool:
        # FIELDGATE_SOCKETCAN_UNSAFE_KEEP_AVX=1 is for the runner's own tests: the guard must refuse
        return os.environ.get("FIELDGATE_SOCKETCAN_UNSAFE_KEEP_AVX") != "1"

    def argv(self, work: Path, mem: str) -> list[str]:
        # On the kernel's command line, so the guest's init (its first shell) starts with them.
        argv = super().argv(work, mem)
        if self.sse_only():
            argv += [f"GLIBC_TUNABLES={GLIBC_SSE_ONLY}", f"OPENSSL_ia32cap={OPENSSL_SSE_ONLY}"]
        return argv

    def guest_settings(self, work: Path) -> dict[str, str]:
        settings = super().guest_settings(work)
        settings.update(
            SOCKETCAN_NO_XSTATE="1",
            SOCKETCAN_KNOWN_ANSWERS=str(HERE / "known-answers.py"),
            SOCKETCAN_EXPECTED_ANSWERS=expected_answers(self.cache),
        )
        if self.sse_only():
            settings.update(GLIBC_TUNABLES=GLIBC_SSE_ONLY, OPENSSL_ia32cap=OPENSSL_SSE_ONLY)
        return settings


class Qemu(Backend):
    name = "qemu"
    what = "QEMU under software emulation (TCG)"
    default_mem = "2048M"
    native = False

    def distribution_kernel(self) -> str | None:
        kernels = sorted(Path("/boot").glob("vmlinuz-*-amd64"), key=lambda p: _version_key(p.name))
        return str(kernels[-1]) if kernels else None

    def fingerprint(self) -> str:
        extra = file_identity(self.distribution_kernel()) + self.name + (controller_model() or "")
        return host_fingerprint(extra)

    def unavailable(self, install: bool) -> str | None:
        if os.uname().machine != "x86_64":
            return f"set up for x86_64 guests only (this host: {os.uname().machine})"
        if install:
            reason = apt_install(QEMU_PACKAGES, f"{self.name}: first use, 1-2 minutes")
            if reason:
                return reason
        missing = [
            c for c in ("qemu-system-x86_64", "busybox", "cpio", "modprobe") if not shutil.which(c)
        ]
        if missing:
            return f"not installed: {', '.join(missing)} (packages {' '.join(QEMU_PACKAGES)})"
        kernel = self.distribution_kernel()
        if kernel is None:
            return "no distribution kernel /boot/vmlinuz-*-amd64 (package linux-image-amd64)"
        return self.controllers_unavailable(kernel)

    def controllers_unavailable(self, kernel: str) -> str | None:
        """Why the emulated controllers asked for cannot run here: QEMU lacks the device
        model, or the guest kernel the driver for it."""
        model = controller_model()
        if model is None:
            return None
        if model not in CONTROLLER_DRIVERS:
            return (
                f"unknown CAN controller model {model!r} (one of {', '.join(CONTROLLER_DRIVERS)})"
            )
        models = subprocess.run(
            ["qemu-system-x86_64", "-device", "help"], capture_output=True, text=True
        ).stdout
        if f'"{model}"' not in models:
            return f"this QEMU has no {model} device model"
        kver = Path(kernel).name.removeprefix("vmlinuz-")
        driver = CONTROLLER_DRIVERS[model]
        found = subprocess.run(
            ["modinfo", "-k", kver, "-F", "filename", driver], capture_output=True
        )
        if found.returncode != 0:
            return f"the guest kernel {kver} has no {driver} module (the driver of {model})"
        return None

    def prepare(self) -> None:
        kernel = self.distribution_kernel()
        assert kernel is not None
        self.initrd = build_initrd(self.cache, kernel)

    def accel(self) -> list[str]:
        return ["-accel", "tcg,thread=multi", "-cpu", "max"]

    def controllers(self) -> list[str]:
        """QEMU arguments for the emulated CAN controllers: CONTROLLER_COUNT devices of the
        model asked for, all on one QEMU can-bus (a wire the guest cannot tell from a real one
        at the driver level; no bit-level timing, so no error frames are ever generated)."""
        model = controller_model()
        if model is None:
            return []
        argv = ["-object", "can-bus,id=canbus0"]
        for _ in range(CONTROLLER_COUNT):
            argv += ["-device", f"{model},canbus=canbus0"]
        return argv

    def guest_settings(self, work: Path) -> dict[str, str]:
        model = controller_model()
        if model is None:
            return {}
        return {
            "SOCKETCAN_CONTROLLER_DRIVER": CONTROLLER_DRIVERS.get(model, model),
            "SOCKETCAN_CONTROLLER_COUNT": str(CONTROLLER_COUNT),
        }

    def argv(self, work: Path, mem: str) -> list[str]:
        opts = "trans=virtio,version=9p2000.L,msize=512000,cache=loose"
        return [
            "qemu-system-x86_64",
            *self.accel(),
            "-smp",
            str(min(os.cpu_count() or 1, 4)),
            "-m",
            mem,
            "-display",
            "none",
            "-no-reboot",
            "-nodefaults",
            "-chardev",
            "stdio,id=console,signal=off",
            "-serial",
            "chardev:console",
            "-kernel",
            str(self.distribution_kernel()),
            "-initrd",
            str(self.initrd),
            "-virtfs",
            "local,path=/,mount_tag=hostroot,security_model=passthrough,multidevs=remap",
            *self.controllers(),
            "-append",
            f"console=ttyS0 quiet loglevel=1 panic=-1 vmrun={work} vm9p={opts}",
        ]


class Kvm(Qemu):
    name = "kvm"
    what = "QEMU with KVM (hardware virtualization)"
    native = True

    def unavailable(self, install: bool) -> str | None:
        if not os.path.exists("/dev/kvm"):
            return "no /dev/kvm"
        if not os.access("/dev/kvm", os.R_OK | os.W_OK):
            return "/dev/kvm is not readable and writable by this user"
        if not (Path("/sys/module/kvm_intel").exists() or Path("/sys/module/kvm_amd").exists()):
            if Path("/sys/module/kvm_pvm").exists():
                return "/dev/kvm is served by kvm_pvm, which runs only guest kernels built for PVM"
            return "/dev/kvm is not served by kvm_intel or kvm_amd"
        return super().unavailable(install)

    def accel(self) -> list[str]:
        return ["-enable-kvm", "-cpu", "host"]


def _version_key(name: str) -> list[int]:
    return [int(n) for n in re.findall(r"\d+", name)]


def build_initrd(cache: Cache, kernel: str) -> Path:
    """A busybox initramfs that loads virtio and 9p, mounts the host's / and hands over to
    guest-init.sh (built once per kernel)."""
    kver = Path(kernel).name.removeprefix("vmlinuz-")
    target = cache.dir / f"initrd-{kver}.cpio.gz"
    if target.exists():
        return target
    say(f"building the QEMU initramfs for {kver} (first use)")
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for sub in ("bin", "mods", "newroot", "proc", "dev"):
            (root / sub).mkdir()
        shutil.copy(shutil.which("busybox") or "", root / "bin/busybox")
        for applet in ("sh", "cat", "mount", "insmod", "switch_root", "sleep"):
            (root / "bin" / applet).symlink_to("busybox")
        deps = subprocess.run(
            ["modprobe", "-S", kver, "--show-depends", "-a", "virtio_pci", "9pnet_virtio", "9p"],
            capture_output=True,
            text=True,
        )
        if deps.returncode != 0:
            raise RuntimeError(
                f"modprobe cannot resolve virtio/9p for {kver}: {deps.stderr.strip()}"
            )
        order: list[str] = []
        for line in deps.stdout.splitlines():
            parts = line.split()
            if len(parts) >= 2 and parts[0] == "insmod" and Path(parts[1]).name not in order:
                shutil.copy(parts[1], root / "mods")
                order.append(Path(parts[1]).name)
        (root / "mods/order").write_text("\n".join(order) + "\n")
        init = root / "init"
        init.write_text(
            "#!/bin/sh\n"
            "for m in $(cat /mods/order); do insmod /mods/$m; done\n"
            "mount -t devtmpfs dev /dev\n"
            'for i in 1 2 3 4 5 6 7 8 9 10; do mount -t 9p -o "$vm9p" hostroot /newroot && break; sleep 0.2; done\n'
            'exec switch_root /newroot /bin/sh "$vmrun/init"\n'
        )
        init.chmod(0o755)
        files = subprocess.run(["find", "."], cwd=root, capture_output=True, check=True).stdout
        archive = subprocess.run(
            ["cpio", "-o", "-H", "newc", "--quiet"],
            cwd=root,
            input=files,
            capture_output=True,
            check=True,
        ).stdout
        tmp_target = target.with_name(target.name + f".{os.getpid()}")
        subprocess.run(["gzip", "-1"], input=archive, stdout=tmp_target.open("wb"), check=True)
        tmp_target.replace(target)
    return target


def expected_answers(cache: Cache) -> str:
    """The host's digest of known-answers.py, kept while the script and the venv's packages
    stay the same."""
    script = HERE / "known-answers.py"
    packages = sorted(venv().glob("lib/python*/site-packages/*.dist-info"))
    key = hashlib.sha256(
        script.read_bytes() + "\n".join(p.name for p in packages).encode() + python().encode()
    ).hexdigest()[:16]
    kept = cache.dir / f"known-answers-{key}"
    if kept.exists():
        return kept.read_text().strip()
    done = subprocess.run(
        [python(), str(script)],
        capture_output=True,
        text=True,
        env=dict(os.environ, PYTHONHASHSEED="0"),
    )
    line = (done.stdout.strip().splitlines()[-1:] or [""])[0]
    if done.returncode != 0 or not line.startswith("known-answers "):
        raise RuntimeError(f"known-answers.py failed on the host: {done.stderr.strip()[-300:]}")
    kept.write_text(line.removeprefix("known-answers "))
    return kept.read_text()


def python() -> str:
    return str(venv() / "bin" / "python")


def venv() -> Path:
    return Path(os.environ.get("FIELDGATE_VENV", REPO / ".venv"))
