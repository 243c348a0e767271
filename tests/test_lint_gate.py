"""scripts/lint, the gate .ci/run runs before the tests: clean on this tree, failing on a
type error or a lint finding, and naming the real file (core/..., not the link tree mypy reads)."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _tools_missing() -> str | None:
    bin_dir = Path(sys.executable).parent
    missing = [tool for tool in ("ruff", "mypy") if not (bin_dir / tool).exists()]
    if missing:
        return f"{', '.join(missing)} not installed in {bin_dir} (pip install -e '.[test]')"
    # scripts/lint sources scripts/ensure-venv, which reinstalls (from the copy!) into a venv
    # whose stamp does not match: only lint with a venv that script made for this tree
    stamp = bin_dir.parent / ".fieldgate-installed"
    want = hashlib.sha256(
        (ROOT / "pyproject.toml").read_bytes()
        + (ROOT / "tests" / "plugin_pkg" / "pyproject.toml").read_bytes()
        + (ROOT / "examples" / "plugins" / "fieldgate-jsonfile" / "pyproject.toml").read_bytes()
    ).hexdigest()
    if not stamp.exists() or stamp.read_text().strip() != want:
        return f"{bin_dir.parent} was not set up by scripts/ensure-venv for this pyproject.toml"
    return None


@pytest.fixture(scope="module")
def tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the tracked files (and this checkout's edits), linted with this venv."""
    reason = _tools_missing()
    if reason:
        if os.environ.get("CI") == "true":
            pytest.fail(reason)
        pytest.skip(reason)
    files = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT,
        capture_output=True,
        check=True,
    ).stdout.split(b"\0")
    copy = tmp_path_factory.mktemp("lint") / "tree"
    for name in filter(None, files):
        source = ROOT / name.decode()
        if source.is_file():
            target = copy / name.decode()
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, target)
    return copy


def lint(tree: Path) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, FIELDGATE_VENV=str(Path(sys.executable).parent.parent))
    return subprocess.run(
        ["bash", "scripts/lint"], cwd=tree, env=env, capture_output=True, text=True, timeout=300
    )


def test_the_tree_passes_the_gate_and_a_type_error_or_lint_finding_fails_it(tree: Path) -> None:
    clean = lint(tree)
    assert clean.returncode == 0, clean.stdout + clean.stderr

    image = tree / "core" / "image.py"
    image.write_text(image.read_text() + '\n\nNOT_AN_INT: int = "x"\n')
    typed = lint(tree)
    assert typed.returncode == 1
    assert "core/image.py:" in typed.stdout and "[assignment]" in typed.stdout
    assert "build/typecheck" not in typed.stdout

    image.write_text(image.read_text().replace('NOT_AN_INT: int = "x"', "import os"))
    linted = lint(tree)
    assert linted.returncode == 1
    assert "F401" in linted.stdout + linted.stderr
