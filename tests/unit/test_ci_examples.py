"""examples/ci: the GitHub Actions workflow and the GitLab CI job, checked as their hosts would."""

import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import REPO

EXAMPLES = REPO / "examples" / "ci"
GITHUB = EXAMPLES / "github-actions.yml"
GITLAB = EXAMPLES / "gitlab-ci.yml"
BIN = Path(sys.executable).parent


def check_schema(schema: str, path: Path) -> subprocess.CompletedProcess:
    """check-jsonschema against the schema it vendors (offline): GitHub's and GitLab's published ones."""
    argv = [str(BIN / "check-jsonschema"), "--builtin-schema", f"vendor.{schema}", str(path)]
    return subprocess.run(argv, capture_output=True, text=True, check=False)


def actionlint(path: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / "actionlint"), str(path)], capture_output=True, text=True, check=False)


@pytest.mark.parametrize(("schema", "path"), [("github-workflows", GITHUB), ("gitlab-ci", GITLAB)])
def test_each_example_matches_its_published_schema_and_a_broken_copy_does_not(schema, path, tmp_path):
    result = check_schema(schema, path)
    assert result.returncode == 0, result.stdout + result.stderr
    broken = tmp_path / path.name
    text = path.read_text()
    broken.write_text(text.replace("runs-on:", "runs_on:") if path == GITHUB else text.replace("script:", "scripts:"))
    assert check_schema(schema, broken).returncode != 0


def test_the_workflow_passes_actionlint_and_a_broken_copy_does_not(tmp_path):
    result = actionlint(GITHUB)
    assert result.returncode == 0, result.stdout + result.stderr
    broken = tmp_path / GITHUB.name
    broken.write_text(
        GITHUB.read_text().replace("${{ vars.ESPDOCK_CACHE_REGISTRY }}", "${{ vars.ESPDOCK_CACHE_REGISTRY")
    )
    assert actionlint(broken).returncode != 0


@pytest.mark.parametrize("path", [GITHUB, GITLAB])
def test_each_example_builds_locked_reports_and_pushes_only_from_the_main_branch(path):
    text = path.read_text()
    assert "espdock build --locked --report report.json" in text
    assert "--require-hashes -r ci/espdock-lock.txt" in text and "--no-deps" in text
    assert "--password-stdin" in text, "credentials go to the engine's login, never on a command line"
    push = text.index("--push-cache")
    main = "refs/heads/main" if path == GITHUB else "$CI_DEFAULT_BRANCH"
    assert main in text[push - 300 : push], "--push-cache is guarded by a main-branch check"
    # What it uploads is where espdock installs (colcon root ws/ in the default layout).
    assert "ws/install/*/share/*/firmware" in text and "ws/install/espdock-manifest.json" in text


def test_actions_are_pinned_by_commit():
    uses = [
        line.split("uses:", 1)[1].split("#")[0].strip() for line in GITHUB.read_text().splitlines() if "uses:" in line
    ]
    assert uses and all(len(ref.split("@")[1]) == 40 for ref in uses), uses
