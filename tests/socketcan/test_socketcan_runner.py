""".ci/socketcan/run itself, on the host: the command's output and exit code come back, a hung
guest times out, a backend that cannot boot is remembered and the next one runs, and the
vector guard refuses a guest whose vector state is corrupted.

The contract tests run on the backend the runner chooses on this host; every other backend is
skipped with its reason (the one the runner itself gives), except uml-noxstate, which is also
tested wherever it can boot: it is the backend of hosts where plain UML panics (CPUs with AMX),
and its guard must work before such a host needs it. Each boot takes 2-8 s on a native-speed
backend.
"""

from __future__ import annotations

import os
import platform
import re
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
RUN = REPO / ".ci" / "socketcan" / "run"
BACKENDS = ("uml", "uml-noxstate", "kvm", "qemu")

pytestmark = pytest.mark.skipif(
    os.environ.get("FIELDGATE_SOCKETCAN_GUEST") is not None
    or platform.system() != "Linux"
    or platform.machine() != "x86_64",
    reason="runs on an x86-64 Linux host, not inside a SocketCAN guest",
)


def run(
    *command: str,
    backend: str | None = None,
    timeout_s: int | None = None,
    tmpdir: Path | None = None,
    extra_env: dict[str, str] | None = None,
    wait_s: int = 300,
) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ)
    env.pop("FIELDGATE_SOCKETCAN_BACKEND", None)
    if tmpdir is not None:
        env["TMPDIR"] = str(tmpdir)  # the runner's work directory (and UML's memory) go here
    if timeout_s is not None:
        env["FIELDGATE_SOCKETCAN_TIMEOUT"] = str(timeout_s)
    env.update(extra_env or {})
    argv = [str(RUN), *(["--backend", backend] if backend else []), *command]
    return subprocess.run(argv, capture_output=True, text=True, env=env, timeout=wait_s)


def backend_table() -> dict[str, tuple[bool, str]]:
    """`--list`: each backend, whether it can run here, and why not (boots nothing)."""
    done = run("--list")
    assert done.returncode == 0, done.stderr
    table = {}
    for line in done.stdout.splitlines():
        found = re.fullmatch(r"(\S+)\s+(ok|no)\s+(native speed|emulated)\s+(.+)", line)
        assert found, line
        table[found.group(1)] = (found.group(2) == "ok", found.group(4))
    return table


@pytest.fixture(scope="module")
def chosen() -> str:
    """The backend the runner chooses here, from a first boot (skips when none can run)."""
    done = run("true")
    if done.returncode == 125:
        pytest.fail(f"no SocketCAN backend can run on this host:\n{done.stderr}")
    assert done.returncode == 0, done.stderr
    found = re.search(r"chose ([\w-]+)", done.stderr)
    assert found, done.stderr
    return found.group(1)


def test_list_names_every_backend_with_a_reason():
    table = backend_table()
    assert list(table) == list(BACKENDS)
    for name, (_usable, why) in table.items():
        assert why, f"{name}: no description or reason"
    kvm_usable, kvm_why = table["kvm"]
    if not (Path("/sys/module/kvm_intel").exists() or Path("/sys/module/kvm_amd").exists()):
        assert not kvm_usable and "kvm" in kvm_why.lower()


def test_command_output_exit_code_and_environment_come_back(chosen):
    done = run(
        "sh",
        "-c",
        'echo "on $(cat /sys/class/net/vcan0/type) as $FIELDGATE_TEST_CAN in $PWD'
        ' guest $FIELDGATE_SOCKETCAN_GUEST slowdown $FIELDGATE_SOCKETCAN_SLOWDOWN"; exit 7',
    )
    assert done.returncode == 7, done.stderr
    # ARPHRD_CAN = 280: vcan0 is a real CAN device in the guest
    assert f"on 280 as socketcan:vcan0 in {REPO} guest {chosen} slowdown " in done.stdout
    slowdown = float(done.stdout.split("slowdown ")[1].split()[0])
    assert slowdown >= 1.0
    assert f"chose {chosen}" in done.stderr
    assert "command exit code 7" in done.stderr
    assert "guard: xmm ok" in done.stderr  # the vector guard ran before the command


def test_arguments_keep_their_quoting(chosen):
    done = run("python", "-c", "import sys; print(sys.argv[1:])", "two words", "$HOME", "a'b")
    assert done.returncode == 0, done.stderr
    assert done.stdout == "['two words', '$HOME', \"a'b\"]\n"  # nothing of the guest's console


def test_a_hung_guest_times_out_with_124_and_leaves_nothing_behind(chosen, tmp_path):
    done = run("sleep", "600", timeout_s=8, tmpdir=tmp_path)
    assert done.returncode == 124, done.stderr
    assert "timed out after 8s" in done.stderr
    # every guest process carries the work directory (under tmp_path) on its command line
    leftovers = subprocess.run(["pgrep", "-f", str(tmp_path)], capture_output=True, text=True)
    assert leftovers.stdout == ""
    assert list(tmp_path.iterdir()) == []  # the work directory is gone


def test_emulated_controllers_are_offered_by_qemu_only_with_a_model_it_knows(tmp_path):
    """`--can-controllers=MODEL` (docs/socketcan.md): UML has no PCI bus; QEMU refuses a model it
    lacks before booting anything (a cache of the test's own: no remembered verdicts)."""
    env = {"FIELDGATE_SOCKETCAN_CACHE": str(tmp_path / "cache")}
    done = run("--can-controllers=nosuch_pci", "--list", extra_env=env)
    assert done.returncode == 0, done.stderr
    lines = {line.split()[0]: line for line in done.stdout.splitlines() if line.strip()}
    for name in ("uml", "uml-noxstate"):
        if "x86_64 only" not in lines[name]:
            assert "no PCI bus: emulated CAN controllers need QEMU" in lines[name]
    if "not installed" not in lines["qemu"]:
        assert "unknown CAN controller model 'nosuch_pci'" in lines["qemu"]
    assert list(tmp_path.glob("fieldgate-socketcan.*")) == []  # nothing booted


def test_install_only_boots_no_guest(tmp_path):
    done = run("--install", tmpdir=tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout == ""
    assert "booting" not in done.stderr and "command exit code" not in done.stderr
    assert list(tmp_path.iterdir()) == []  # no work directory was made


def test_an_unknown_backend_is_a_usage_error():
    done = run("true", backend="vmware")
    assert done.returncode != 0
    assert "unknown backend 'vmware'" in done.stderr


@pytest.mark.parametrize("backend", BACKENDS)
def test_each_backend_boots_with_vcan0_and_its_guard(backend, chosen):
    usable, why = backend_table()[backend]
    if not usable:
        pytest.skip(f"{backend} cannot run on this host: {why}")
    if backend != chosen and backend != "uml-noxstate":
        pytest.skip(f"{backend} is not the backend chosen here ({chosen} is): {why}")
    done = run(
        "sh",
        "-c",
        'echo "$FIELDGATE_SOCKETCAN_GUEST $(cat /sys/class/net/vcan0/type)";'
        ' printf "%s=%d\\n" printf 42; python3 -c "print(sum(range(10**5)))"',
        backend=backend,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == [f"{backend} 280", "printf=42", "4999950000"]
    guard = re.search(r"guard: (.*)", done.stderr)
    assert guard, done.stderr
    assert "xmm ok (0 bad" in guard.group(1)
    if backend == "uml-noxstate":
        # AVX state is not preserved there; the known answers must then match the host's
        assert "known-answers " in guard.group(1)


def test_the_guard_refuses_a_guest_with_corrupted_vector_state():
    usable, why = backend_table()["uml-noxstate"]
    if not usable:
        pytest.skip(f"uml-noxstate cannot run on this host: {why}")
    done = run(
        "sh",
        "-c",
        "echo the command ran",
        backend="uml-noxstate",
        extra_env={"FIELDGATE_SOCKETCAN_UNSAFE_KEEP_AVX": "1"},  # glibc left on its AVX paths
    )
    assert done.returncode == 125, done.stdout + done.stderr
    assert "the command ran" not in done.stdout
    assert "uml-noxstate cannot run here" in done.stderr


def test_a_backend_that_cannot_boot_is_remembered_and_the_next_one_runs(tmp_path):
    usable, why = backend_table()["uml-noxstate"]
    if not usable:
        pytest.skip(f"uml-noxstate cannot run on this host: {why}")
    # plain uml fails at boot as it does on hosts with AMX; a private cache of verdicts
    env = {
        "FIELDGATE_SOCKETCAN_TEST_BREAK": "uml",
        "FIELDGATE_SOCKETCAN_CACHE": str(tmp_path / "cache"),
    }
    first = run(
        "sh",
        "-c",
        "echo ran on $FIELDGATE_SOCKETCAN_GUEST",
        backend="uml,uml-noxstate",
        extra_env=env,
    )
    assert first.returncode == 0, first.stderr
    assert first.stdout == "ran on uml-noxstate\n"
    assert "uml cannot run here" in first.stderr
    assert "ptrace set fp regs failed" in first.stderr  # the reason, from the guest's console
    second = run(
        "sh",
        "-c",
        "echo again on $FIELDGATE_SOCKETCAN_GUEST",
        backend="uml,uml-noxstate",
        extra_env=env,
    )
    assert second.returncode == 0, second.stderr
    assert second.stdout == "again on uml-noxstate\n"
    assert "remembered" in second.stderr and "booting uml " not in second.stderr
    # one backend named alone is tried even though it is remembered; failing, it ends with 125
    alone = run("true", backend="uml", extra_env=env)
    assert alone.returncode == 125
    assert "no backend could run the command" in alone.stderr
