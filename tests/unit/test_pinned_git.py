"""docker/idf/pinned_git.py: libmicroros.mk's branch-head clones become pinned checkouts (real git)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import REPO

SHIM = REPO / "docker/idf/pinned_git.py"
GIT = "/usr/bin/git"


def git(*args: str, cwd: Path | None = None) -> str:
    env = {**os.environ, "GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@example.com",
           "GIT_COMMITTER_NAME": "t", "GIT_COMMITTER_EMAIL": "t@example.com"}  # fmt: skip
    return subprocess.run([GIT, *args], cwd=cwd, env=env, check=True, capture_output=True, text=True).stdout.strip()


@pytest.fixture
def upstream(tmp_path):
    """A repository on branch jazzy with two commits; returns (url, pinned commit, head commit)."""
    work = tmp_path / "upstream"
    work.mkdir()
    git("init", "-q", "--initial-branch=jazzy", cwd=work)
    (work / "VERSION").write_text("pinned\n")
    git("add", "-A", cwd=work)
    git("commit", "-q", "-m", "pinned", cwd=work)
    pinned = git("rev-parse", "HEAD", cwd=work)
    (work / "VERSION").write_text("moved on\n")
    git("commit", "-q", "-am", "moved on", cwd=work)
    git("config", "uploadpack.allowAnySHA1InWant", "true", cwd=work)
    return f"file://{work}", pinned, git("rev-parse", "HEAD", cwd=work)


def clone(tmp_path: Path, pins: str, *args: str) -> subprocess.CompletedProcess:
    sources = tmp_path / "micro_ros_sources.txt"
    sources.write_text(pins)
    env = {**os.environ, "ESPDOCK_REAL_GIT": GIT, "ESPDOCK_MICRO_ROS_SOURCES": str(sources),
           "ESPDOCK_PIN_FAILURES": str(tmp_path / "failures")}  # fmt: skip
    command = [sys.executable, str(SHIM), *args]
    return subprocess.run(command, cwd=tmp_path, env=env, capture_output=True, text=True, check=False)


def test_a_head_that_is_not_pinned_is_taken_with_a_warning_and_recorded(tmp_path, upstream):
    url, _, head = upstream
    resolved = tmp_path / "resolved"
    sources = tmp_path / "micro_ros_sources.txt"
    sources.write_text(f"{url} jazzy -\n")
    env = {**os.environ, "ESPDOCK_REAL_GIT": GIT, "ESPDOCK_MICRO_ROS_SOURCES": str(sources),
           "ESPDOCK_MICRO_ROS_RESOLVED": str(resolved), "ESPDOCK_PIN_FAILURES": str(tmp_path / "failures")}  # fmt: skip
    result = subprocess.run([sys.executable, str(SHIM), "clone", "-b", "jazzy", url, "src/up"], cwd=tmp_path,
                            env=env, capture_output=True, text=True, check=False)  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert f"{url} is not pinned; took {head}" in result.stderr
    assert resolved.read_text() == f"{url} jazzy {head}\n"


def test_a_branch_clone_checks_out_the_pinned_commit_not_the_head(tmp_path, upstream):
    url, pinned, head = upstream
    result = clone(tmp_path, f"# comment\n{url}.git jazzy {pinned}\n", "clone", "-b", "jazzy", url, "src/up")
    assert result.returncode == 0, result.stderr
    assert git("rev-parse", "HEAD", cwd=tmp_path / "src/up") == pinned != head
    assert (tmp_path / "src/up/VERSION").read_text() == "pinned\n"
    assert not (tmp_path / "failures").exists()


def test_an_unpinned_repository_fails_and_is_recorded(tmp_path, upstream):
    url, pinned, _ = upstream
    result = clone(tmp_path, f"file:///elsewhere jazzy {pinned}\n", "clone", "-b", "jazzy", url, "src/up")
    assert result.returncode == 1
    assert f"{url} is cloned by the micro-ROS build but not pinned" in result.stderr
    assert url in (tmp_path / "failures").read_text()
    assert not (tmp_path / "src/up").exists()


def test_another_branch_than_the_pinned_one_fails(tmp_path, upstream):
    url, pinned, _ = upstream
    result = clone(tmp_path, f"{url} jazzy {pinned}\n", "clone", "-b", "kilted", url, "src/up")
    assert result.returncode == 1 and "pins it on jazzy" in result.stderr


def test_a_malformed_pin_names_its_line(tmp_path, upstream):
    url, _, _ = upstream
    result = clone(tmp_path, f"{url} jazzy abc123\n", "clone", "-b", "jazzy", url, "src/up")
    assert result.returncode != 0 and "micro_ros_sources.txt:1:" in result.stderr


def test_other_git_commands_go_to_the_real_git(tmp_path):
    result = clone(tmp_path, "", "--version")
    assert result.returncode == 0 and result.stdout.startswith("git version")


def test_the_shipped_pins_parse(tmp_path):
    result = clone(tmp_path, (REPO / "docker/idf/micro_ros_sources.txt").read_text(), "clone", "file:///x")
    assert "not pinned" in result.stderr, result.stderr


def test_a_clone_under_git_dash_c_dir_is_pinned_there_and_has_its_remote(tmp_path, upstream):
    url, pinned, _ = upstream
    (tmp_path / "src").mkdir()
    result = clone(tmp_path, f"{url} jazzy {pinned}\n", "-C", "src", "clone", "-b", "jazzy", url, "up")
    assert result.returncode == 0, result.stderr
    assert git("rev-parse", "HEAD", cwd=tmp_path / "src/up") == pinned
    assert git("remote", "get-url", "origin", cwd=tmp_path / "src/up") == url
    assert git("rev-parse", "--abbrev-ref", "HEAD", cwd=tmp_path / "src/up") == "jazzy"


@pytest.mark.parametrize(
    "args",
    [
        ("-c", "core.autocrlf=true", "clone", "-b", "jazzy", "URL", "up"),
        ("clone", "--template", "/tmp/t", "-b", "jazzy", "URL", "up"),
        ("clone", "-j", "4", "URL", "up"),
        ("clone", "--reference-if-able", "/tmp/r", "URL", "up"),
        ("clone", "--shallow-since", "2024-01-01", "URL", "up"),
        ("clone", "--recursive", "-b", "jazzy", "URL", "up"),
        ("clone", "--no-checkout", "URL", "up"),
    ],
)
def test_what_a_pinned_clone_cannot_honour_is_refused_loudly(tmp_path, upstream, args):
    url, pinned, _ = upstream
    argv = [url if a == "URL" else a for a in args]
    result = clone(tmp_path, f"{url} jazzy {pinned}\n", *argv)
    assert result.returncode == 1
    assert "pinned git: error:" in result.stderr
    assert "cannot honour" in result.stderr or "honours only" in result.stderr
    assert (tmp_path / "failures").read_text(), "the Dockerfile's check would miss it"
    assert not (tmp_path / "up").exists()


def test_a_tag_checkout_after_a_pinned_clone_fails_naming_the_tag(tmp_path, upstream):
    """What the Micro-XRCE-DDS-Client superbuild would do with micro-CDR: no tags come along."""
    url, pinned, _ = upstream
    assert clone(tmp_path, f"{url} jazzy {pinned}\n", "clone", url, "up").returncode == 0
    checkout = subprocess.run(
        [GIT, "-C", str(tmp_path / "up"), "checkout", "v2.0.1"], capture_output=True, text=True, check=False
    )
    assert checkout.returncode != 0 and "v2.0.1" in checkout.stderr
