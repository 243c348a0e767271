"""A broken installed plugin is contained: ``fieldgate plugins`` reports it (exit 1, the
reason in one line), ``validate`` and ``run`` name it only when the topology needs it, and
everything else keeps working.

The broken plugin is installed the way pip installs any distribution: a ``.dist-info``
folder with its entry points and the module beside it, on the path of the processes run.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from fieldgate import hookimpl, load_registry

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "i7232d-style.yaml"


def install_broken(site: Path) -> None:
    """fieldgate-broken 0.3: plugin ``csvfile`` fails to import, plugin ``halfway`` fails
    while registering, after it registered a back type, and plugin ``jsonfile`` has the name
    of the guide's example plugin (installed in the test venv)."""
    site.mkdir(parents=True, exist_ok=True)
    (site / "fieldgate_broken_import.py").write_text(
        '"""A plugin whose dependency is missing."""\nimport fieldgate_missing_dependency\n'
    )
    (site / "fieldgate_broken_halfway.py").write_text(
        '"""A plugin that fails in the middle of registering."""\n'
        "from fieldgate import hookimpl\n"
        "from fieldgate_loopback import LoopbackBack, LoopbackConfig\n\n"
        "@hookimpl\n"
        "def fieldgate_register(registry):\n"
        '    registry.add_back("halfway", LoopbackConfig, LoopbackBack)\n'
        '    raise RuntimeError("cannot find its license file")\n'
    )
    (site / "fieldgate_broken_named.py").write_text('"""A plugin named like another one."""\n')
    info = site / "fieldgate_broken-0.3.dist-info"
    info.mkdir(exist_ok=True)
    (info / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: fieldgate-broken\nVersion: 0.3\nSummary: broken on purpose\n"
    )
    (info / "entry_points.txt").write_text(
        "[fieldgate.plugins]\n"
        "csvfile = fieldgate_broken_import\n"
        "halfway = fieldgate_broken_halfway\n"
        "jsonfile = fieldgate_broken_named\n"
    )
    (info / "top_level.txt").write_text(
        "fieldgate_broken_import\nfieldgate_broken_halfway\nfieldgate_broken_named\n"
    )


@pytest.fixture(scope="module")
def broken_env(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    site = tmp_path_factory.mktemp("broken") / "site"
    install_broken(site)
    path = os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")]))
    return {**os.environ, "PYTHONPATH": path}


def fieldgate(
    env: dict[str, str], *args: str, cwd: Path = REPO
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "fieldgate", *args],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
        cwd=cwd,
    )


def test_fieldgate_plugins_exits_1_and_gives_each_failure_in_one_line(broken_env):
    result = fieldgate(broken_env, "plugins")
    assert result.returncode == 1, result.stdout + result.stderr
    rows = {line.split()[0]: line for line in result.stdout.splitlines()}
    assert rows["PLUGIN"].split() == ["PLUGIN", "VERSION", "DISTRIBUTION", "PROVIDES", "SUMMARY"]
    assert rows["csvfile"].endswith(
        "FAILED: ModuleNotFoundError: No module named 'fieldgate_missing_dependency'"
    )
    assert "fieldgate-broken" in rows["csvfile"]
    # two plugins of one name: the first on the path keeps it, the other fails and says why
    assert "FAILED" not in rows["jsonfile"] and "fieldgate-broken" in rows["jsonfile"]
    assert rows["jsonfile@fieldgate-jsonfile"].endswith(
        "FAILED: plugin name 'jsonfile' is taken by fieldgate-broken"
    )
    # what it registered before failing is undone: it provides nothing, not half
    assert rows["halfway"].split()[3] == "-"
    assert rows["halfway"].endswith("FAILED: RuntimeError: cannot find its license file")
    # the others are listed as usual
    assert "FAILED" not in rows["modbus"] and "back:modbus" in rows["modbus"]
    assert result.stderr.strip() == (
        "fieldgate plugins: 3 plugin(s) failed: csvfile, halfway, jsonfile@fieldgate-jsonfile"
    )


def test_a_topology_that_does_not_use_it_validates_and_runs(broken_env):
    valid = fieldgate(broken_env, "validate", str(EXAMPLE))
    assert valid.returncode == 0, valid.stderr
    assert valid.stderr == ""  # not a word about the broken plugins
    run = fieldgate(broken_env, "run", str(EXAMPLE), "--simulate", "--duration", "0.5")
    assert run.returncode == 0, run.stderr
    assert "broken" not in run.stderr and "csvfile" not in run.stderr


def test_a_topology_that_needs_it_names_it_and_its_error(broken_env, tmp_path):
    topology = tmp_path / "files.yaml"
    topology.write_text(
        "gateway: {name: files}\n"
        "fronts: [{name: plc, type: memory}]\n"
        "backs: [{name: lab, type: csvfile, modules: []}]\n"
    )
    for command in ("validate", "run"):
        result = fieldgate(broken_env, command, str(topology))
        assert result.returncode == 1, result.stderr
        (line,) = [text for text in result.stderr.splitlines() if "csvfile" in text]
        assert line.startswith(f"{topology}:3:")
        assert (
            "no installed plugin provides back type 'csvfile'" in line
            and "plugin csvfile (fieldgate-broken) failed to load: ModuleNotFoundError: "
            "No module named 'fieldgate_missing_dependency'"
            in line
        )
        assert "halfway" not in result.stderr  # the plugin named like the type, not every one


def test_a_plugin_that_fails_while_registering_leaves_nothing_behind():
    class Halfway:
        PLUGIN_NAME = "halfway"

        @hookimpl
        def fieldgate_register(self, registry):
            registry.add_back("halfway", object, object)
            registry.add_command(("simulate", "halfway"), "x", lambda p: None, lambda a: 0)
            registry.add_simulator("halfway", object)
            raise RuntimeError("and then\nit failed")

    registry = load_registry(extra_plugins=[Halfway()])
    assert registry.lookup("back", "halfway") is None
    assert all(c.plugin != "halfway" for c in registry.commands)
    assert "halfway" not in registry.simulators
    info = registry.plugins["halfway"]
    assert (info.provides, info.error) == ([], "RuntimeError: and then it failed")
    assert registry.lookup("back", "loopback") is not None  # the others are all there


def test_a_plugin_command_that_cannot_set_up_its_options_breaks_only_itself(capsys):
    from fieldgate.cli import build_parser, cmd_plugins

    class BadOptions:
        PLUGIN_NAME = "badoptions"

        @hookimpl
        def fieldgate_register(self, registry):
            def configure(parser):
                parser.add_argument("--port")
                parser.add_argument("--port")  # argparse refuses a second --port

            registry.add_command(("scan", "bad"), "x", configure, lambda a: 0)

    registry = load_registry(extra_plugins=[BadOptions()])
    parser = build_parser(registry)  # the other commands are still there
    args = parser.parse_args(["scan", "bad"])
    assert args.handler(args, registry) == 2
    assert (
        "fieldgate scan bad: broken in plugin badoptions: ArgumentError" in capsys.readouterr().err
    )
    assert cmd_plugins(args, registry) == 1
    assert parser.parse_args(["validate", "x.yaml"]).file == "x.yaml"
