"""The test run leaves the engine as it found it: the runtime images its builds made go at the end.

Every `espdock build` records the keyed images it used, per workspace, in espdock's state
directory. The run gives its builds a state directory of its own (so they neither read nor
add to the developer's records), and when the run ends removes the runtime images
(espdock/<workspace name>:<key> and :latest) those records name, which the tests' throwaway
workspaces made and a later test of the run may reuse. A tag that was on the engine before the
run started is not the run's and stays; one the run moved to another image goes back.

What stays on purpose: the keyed base images (the ROS build, runtime and test images, the IDF
and micro-ROS images, the doubles standing in for upstream images). Their keys come from this
checkout's files, so the next run finds them and does not rebuild them.

With pytest-xdist the controller does this once: the workers inherit its environment, so their
builds record into the same directory, and it sweeps after they all finished.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest

from espdock.build.steps import LABEL_INPUTS
from espdock.images.prune import read_records

STATE_KEY = pytest.StashKey[Path]()
BEFORE_KEY = pytest.StashKey["Before"]()


LISTING = ["docker", "image", "ls", "--format", "{{.Repository}}:{{.Tag}} {{.ID}}"]


def tagged_images() -> dict[str, str]:
    """Every tag on the engine and its image ID; none when no engine answers (unit tests only)."""
    try:
        listing = subprocess.run(LISTING, capture_output=True, text=True, check=True, timeout=60)
    except (OSError, subprocess.SubprocessError):
        return {}
    return _tags(listing.stdout)


def _tags(listing: str) -> dict[str, str]:
    return dict(line.split() for line in listing.splitlines() if "<none>" not in line)


class Before:
    """The engine's tags as the run starts, asked in the background: an engine that accepts and
    never answers (a remote DOCKER_HOST off the VPN) held `make unit`, which needs none, for a
    minute at the start and another at the end. A first build takes seconds, the listing a tenth."""

    def __init__(self) -> None:
        try:
            self._process: subprocess.Popen | None = subprocess.Popen(
                LISTING, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True
            )
        except OSError:
            self._process = None

    def tags(self) -> dict[str, str]:
        if self._process is None:
            return {}
        try:
            out, _ = self._process.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            self.stop()
            return {}
        return _tags(out) if self._process.returncode == 0 else {}

    def stop(self) -> None:
        if self._process is not None and self._process.poll() is None:
            self._process.kill()
            self._process.communicate()


def is_runtime_image(inspected: dict) -> bool:
    """Whether an image is a workspace's runtime image: made from an install tree, which the
    image's recorded inputs name (a keyed base image is made from files of the checkout)."""
    labels = (inspected.get("Config") or {}).get("Labels") or {}
    try:
        return "install" in json.loads(labels.get(LABEL_INPUTS, "{}"))
    except ValueError:
        return False


def runtime_tags(state: Path, before: dict[str, str]) -> list[str]:
    """The runtime images the builds recorded in STATE made, with their repositories' :latest,
    leaving out every tag BEFORE had for the same image."""
    recorded = {image.tag: image.repository for record in read_records(state) for image in record.images}
    now = tagged_images()
    # A :latest may have moved where the keyed tag did not: two test workspaces of one name
    # (two "official"s) both had their runtime images on the engine before the run.
    latest = {f"{repository}:latest" for repository in recorded.values()}
    candidates = sorted(tag for tag in recorded.keys() | latest if tag in now and before.get(tag) != now[tag])
    if not candidates:
        return []
    # A tag gone meanwhile is left out of the answer, which lists the others (and exits 1).
    inspect = subprocess.run(
        ["docker", "image", "inspect", *candidates], capture_output=True, text=True, check=False, timeout=60
    )
    images = json.loads(inspect.stdout or "[]")
    named = {tag for image in images if is_runtime_image(image) for tag in image.get("RepoTags") or ()}
    return [tag for tag in candidates if tag in named]


@pytest.hookimpl(tryfirst=True)
def pytest_configure(config: pytest.Config) -> None:
    if hasattr(config, "workerinput"):
        return
    run = Path(tempfile.mkdtemp(prefix="espdock-test-run-"))
    run.chmod(0o755)
    # Builds run as test users record here too: each writes its own workspace's file.
    (run / "state" / "workspaces").mkdir(parents=True)
    (run / "state" / "workspaces").chmod(0o1777)
    os.environ["ESPDOCK_STATE_DIR"] = str(run / "state")
    config.stash[STATE_KEY] = run
    config.stash[BEFORE_KEY] = Before()


def pytest_sessionfinish(session: pytest.Session) -> None:
    run = session.config.stash.get(STATE_KEY, None)
    if run is None:
        return
    if not read_records(run / "state"):
        return  # no build recorded an image
    tags = runtime_tags(run / "state", session.config.stash[BEFORE_KEY].tags())
    if not tags:
        return
    # Without --force: an image a running container uses stays, and says so.
    removed = subprocess.run(["docker", "rmi", *tags], capture_output=True, text=True, check=False, timeout=300)
    # A tag the run moved (a developer's own espdock/robot:latest, when a test's workspace was
    # also named robot) goes back to the image it named before.
    before = session.config.stash[BEFORE_KEY].tags()
    restored = [tag for tag in tags if tag in before and subprocess.run(
        ["docker", "tag", before[tag], tag], capture_output=True, check=False, timeout=60).returncode == 0]  # fmt: skip
    reporter = session.config.pluginmanager.get_plugin("terminalreporter")
    if reporter is not None:
        # On a line of its own: xdist's progress line does not end in a newline the reporter knows of.
        reporter.write_line(f"\nremoved the {len(tags)} runtime image tags this run's builds made: {' '.join(tags)}")
        if restored:
            reporter.write_line(f"and gave back the tags the run had moved: {' '.join(restored)}")
        if removed.returncode != 0:
            reporter.write_line(f"some stay: {removed.stderr.strip()}")


def pytest_unconfigure(config: pytest.Config) -> None:
    if (before := config.stash.get(BEFORE_KEY, None)) is not None:
        before.stop()
    run = config.stash.get(STATE_KEY, None)
    if run is not None:
        os.environ.pop("ESPDOCK_STATE_DIR", None)
        shutil.rmtree(run, ignore_errors=True)
