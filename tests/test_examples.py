"""Every example topology validates, or fails only because its front's plugin is not installed."""

from pathlib import Path

import pytest

from fieldgate import load_registry
from fieldgate.topology import TopologyError, load_topology

EXAMPLES = sorted((Path(__file__).parent.parent / "examples").glob("*.yaml"))
REGISTRY = load_registry()


def test_the_five_examples_exist():
    assert {p.stem for p in EXAMPLES} >= {
        "i7232d-style",
        "i7231d-style",
        "i7241d-style",
        "na9161-style",
        "devicenet-modbus",
    }


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_example_validates_or_needs_only_a_missing_plugin(path):
    text = path.read_text()
    front_types = {
        line.split(":", 1)[1].strip()
        for line in text.splitlines()
        if line.strip().startswith("type:")
    }
    missing = sorted(
        t
        for t in front_types
        if REGISTRY.lookup("front", t) is None and REGISTRY.lookup("back", t) is None
    )
    if not missing:
        topology = load_topology(path, REGISTRY)
        assert topology.channel_specs, "an example without channels shows nothing"
        return
    with pytest.raises(TopologyError) as info:
        load_topology(path, REGISTRY)
    assert len(info.value.issues) == len(missing)
    for issue, type_name in zip(info.value.issues, missing, strict=True):
        assert f"no installed plugin provides front type '{type_name}'" in issue.message
        assert issue.line is not None


def test_the_readme_topology_reference_validates(tmp_path):
    """The reference sample in README.md is a topology that loads, as written."""
    readme = (Path(__file__).parent.parent / "README.md").read_text()
    section = readme.split("## Topology file reference", 1)[1]
    sample = section.split("```yaml\n", 1)[1].split("```", 1)[0]
    path = tmp_path / "readme.yaml"
    path.write_text(sample)
    topology = load_topology(path, REGISTRY)
    assert topology.channel_specs
