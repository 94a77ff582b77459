"""Several workspaces on one engine at once (two users, CI jobs sharing a runner): builds that share
keyed images run side by side, and a second build in one workspace names the one holding it.
The images are this run's own (a comment unique to the run in Dockerfile.ros)."""

from __future__ import annotations

import hashlib
import shutil
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from espdock.images.prune import read_records
from tests.conftest import espdock, images_built_from, locale_env, python_workspace

pytestmark = [pytest.mark.engine, pytest.mark.slow]


def start_build(root: Path, env: dict[str, str]) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "espdock", "build"],
        cwd=root,
        env={**__import__("os").environ, **env},
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def untagged_from(dockerfile: Path) -> list[str]:
    """Untagged images built from DOCKERFILE as it is now."""
    return [image["Id"] for image in images_built_from(dockerfile, untagged=True)]


def test_two_workspaces_sharing_images_build_at_once(engine, tmp_path):
    run = uuid.uuid4().hex[:12]
    env = {"ESPDOCK_STATE_DIR": str(tmp_path / "state")}
    first, second = tmp_path / "first", tmp_path / "second"
    python_workspace(first)
    dockerfile = first / "Dockerfile.ros"
    dockerfile.write_text(dockerfile.read_text() + f"# workspaces test {run}\n")
    shutil.copytree(first, second)
    for root, side in ((first, "a"), (second, "b")):
        (root / "espdock.toml").write_text(f'[espdock]\nname = "shared-{side}-{run}"\nruntime_image = true\n')
    holder = Path("/tmp") / f"espdock-build-{hashlib.sha256(str(first).encode()).hexdigest()[:16]}.holder"
    try:
        builds = [start_build(first, env), start_build(second, env)]
        deadline = time.monotonic() + 120
        while not holder.exists() and time.monotonic() < deadline and builds[0].poll() is None:
            time.sleep(0.05)
        third = espdock("build", cwd=first, env=env)
        assert third.returncode == 2, third.stdout + third.stderr
        assert f"another espdock build is running in {first} (pid {builds[0].pid}: " in third.stderr, third.stderr
        # `python -m espdock build`, named as the command a user would type.
        assert third.stderr.split(f"pid {builds[0].pid}: ")[1].startswith("espdock build"), third.stderr
        outputs = [build.communicate(timeout=1200)[0] for build in builds]
        for build, output in zip(builds, outputs, strict=True):
            assert build.returncode == 0, output[-3000:]
        records = {r.root: r for r in read_records(tmp_path / "state")}
        shared = records[str(first)].current & records[str(second)].current
        assert len(shared) == 2, records  # the ROS build image and the runtime base, one each for both
        for tag in shared:  # one build made it, the other waited and found it
            made = [output for output in outputs if f"{tag}: cache miss" in output]
            assert len(made) == 1, f"{tag} built {len(made)} times:\n" + "\n".join(o[-2000:] for o in outputs)
        assert untagged_from(dockerfile) == [], "a build left the image it raced with on the engine, untagged"
        for root in (first, second):  # both found everything they use: nothing rebuilt
            again = espdock("build", cwd=root, env=env)
            assert again.returncode == 0 and "cache miss" not in again.stdout, again.stdout[-3000:]
    finally:
        tags = {i.tag for r in read_records(tmp_path / "state") for i in r.images}
        tags |= {f"espdock/shared-{side}-{run}:latest" for side in "ab"}
        subprocess.run(["docker", "rmi", *sorted(tags), *untagged_from(dockerfile)], capture_output=True, check=False)


def test_a_build_under_a_latin1_locale_gives_the_engine_the_workspace_s_own_path(engine, tmp_path):
    """LC_ALL=en_US.ISO-8859-1 and a workspace at .../wü: espdock read the path's UTF-8 bytes as
    Latin-1 (wÃ¼), gave the engine that path, which it did not find, and the build went through a
    workspace volume without a word (and `espdock run -v` was then refused)."""
    root = python_workspace(tmp_path / "wü")
    # The run's state dir (the suite's sweep removes the runtime image it records).
    built = espdock("build", cwd=root, env=locale_env(tmp_path, "en_US", "ISO-8859-1"))
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr
    assert "workspace volume" not in built.stdout, built.stdout[-3000:]
    assert (root / "ws/install/beacon_nodes").is_dir()
