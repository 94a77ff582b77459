"""`espdock prune` on the real engine: a workspace with three generations of images and a second
workspace sharing one of them. Every image here is this run's own (a comment unique to the run in
Dockerfile.ros gives each image a key nobody else has) and the records live in this run's state
dir, so nothing another test or user built is ever a candidate."""

from __future__ import annotations

import shutil
import subprocess
import uuid
from pathlib import Path

import pytest

from espdock.build.steps import LABEL_KEY
from espdock.images.engine import Engine
from espdock.images.prune import Record, read_records
from tests.conftest import copy_workspace, espdock
from tests.integration.test_faults import add_package

pytestmark = [pytest.mark.engine, pytest.mark.slow]


def generation(root: Path, run: str, number: int) -> None:
    """Make ROOT's inputs those of generation NUMBER: a new Dockerfile.ros, so new keys for every image."""
    dockerfile = root / "Dockerfile.ros"
    base = dockerfile.read_text().split("# prune test ")[0]
    dockerfile.write_text(f"{base}# prune test {run} generation {number}\n")


def on_engine(engine: Engine) -> set[str]:
    return {tag for _, tags, _, _ in engine.labelled_images(LABEL_KEY) for tag in tags}


def disk(engine: Engine, tags: set[str]) -> tuple[int, int]:
    """What the images TAGS name take: (bytes no other image shares, sizes with shared layers)."""
    listing = [entry for entry in engine.labelled_images(LABEL_KEY, shared=True) if set(entry[1]) & tags]
    return sum(unique for _, _, unique, _ in listing), sum(size for _, _, _, size in listing)


def recorded(state: Path) -> dict[str, Record]:
    return {record.root: record for record in read_records(state)}


def test_prune_keeps_what_is_used_and_removes_the_rest(engine, tmp_path):
    run = uuid.uuid4().hex[:12]
    state = tmp_path / "state"
    env = {"ESPDOCK_STATE_DIR": str(state)}
    first, second = tmp_path / "first", tmp_path / "second"
    # One plain CMake package, no Python and no compiler: prune is about the images, and each of
    # the test's five colcon builds then takes a second, not beacon_nodes' several.
    copy_workspace(first, packages=())
    add_package(first, "prune_pkg", "install(FILES package.xml DESTINATION share/${PROJECT_NAME})\n")
    (first / "espdock.toml").write_text(f'[espdock]\nname = "prune-a-{run}"\nruntime_image = true\n')
    try:
        for number in (1, 2, 3):
            generation(first, run, number)
            if number == 2:  # the second workspace shares the second generation's ROS images
                shutil.copytree(first, second, ignore=shutil.ignore_patterns("build", "install", "log"))
                (second / "espdock.toml").write_text(f'[espdock]\nname = "prune-b-{run}"\nruntime_image = true\n')
                built = espdock("build", cwd=second, env=env)
                assert built.returncode == 0, built.stdout[-3000:] + built.stderr
            built = espdock("build", cwd=first, env=env)
            assert built.returncode == 0, built.stdout[-3000:] + built.stderr
        records = recorded(state)
        ours, theirs = records[str(first)], records[str(second)]
        everything = {i.tag for i in ours.images} | {i.tag for i in theirs.images}
        present = on_engine(engine) & everything
        assert len({i.tag for i in ours.images}) == 9 and len(ours.current) == 3  # 3 kinds x 3 generations
        shared = theirs.current & {i.tag for i in ours.images}
        assert len(shared) == 2  # the ROS build image and the runtime base of generation 2
        gone = {i.tag for i in ours.images} - ours.current - shared  # generation 1, generation 2's runtime

        dry = espdock("prune", "--keep", "0", "--dry-run", cwd=first, env=env)
        assert dry.returncode == 0, dry.stdout + dry.stderr
        assert "recorded its images" not in dry.stdout + dry.stderr
        # A CI job's fresh HOME has no records: it said "would remove 0 images" and no more.
        elsewhere = espdock("prune", "--dry-run", cwd=first, env={"ESPDOCK_STATE_DIR": str(tmp_path / "fresh")})
        said = " ".join(elsewhere.stdout.split())
        assert elsewhere.returncode == 0 and "would remove 0 images" in said, said + elsewhere.stderr
        assert f"note: no build of {first} recorded its images in {tmp_path / 'fresh'}" in said, said
        assert "give them one ESPDOCK_STATE_DIR that lasts" in said, said
        assert on_engine(engine) & everything == present, "a dry run removed images"
        for tag in gone:
            assert f"would remove {tag} (" in dry.stdout, dry.stdout
        for tag in shared:
            assert f"kept {tag} (another workspace's last build used it)" in dry.stdout, dry.stdout
        assert f"would remove {len(gone)} images, " in dry.stdout

        # A stopped container of one of them: the engine refuses to remove its image, and the dry run
        # listed it as going ("would remove"), where the prune then kept it, naming no container.
        held, holder = sorted(gone)[0], f"espdock-test-stopped-{run}"
        subprocess.run(["docker", "create", "--name", holder, held, "true"], capture_output=True, check=True)
        try:
            stopped = espdock("prune", "--keep", "0", "--dry-run", cwd=first, env=env)
            said = f"kept {held} (a stopped container uses it ({holder}; `docker rm {holder}` lets it go))"
            assert said in stopped.stdout and f"would remove {held} " not in stopped.stdout, stopped.stdout
        finally:
            subprocess.run(["docker", "rm", holder], capture_output=True, check=False)

        # The cache's trim is the engine's, not this workspace's: a dry run says so. The engine answers
        # one disk-usage report at a time, and another worker's build may be asking for one.
        for _ in range(5):
            trim = espdock("prune", "--keep", "1", "--dry-run", "--cache-max-gb", "0", cwd=first, env=env)
            if "the engine was busy reporting it" not in trim.stdout:
                break
        said = "would be trimmed to 0 B (the engine's one cache: every workspace's and user's builds)"
        assert said in trim.stdout.replace("\n", " "), trim.stdout
        kept_one = espdock("prune", "--keep", "1", "--dry-run", cwd=first, env=env)
        assert kept_one.stdout.count("would remove espdock/") == len(gone) - 1, kept_one.stdout  # gen 2's runtime stays

        disk_before = disk(engine, everything)
        pruned = espdock("prune", "--keep", "0", cwd=first, env=env)
        assert pruned.returncode == 0, pruned.stdout + pruned.stderr
        after = on_engine(engine)
        disk_after = disk(engine, everything)
        print(f"\n{pruned.stdout.splitlines()[-1]}\nthis run's images: unique {disk_before[0]} -> {disk_after[0]} B, "
              f"with shared layers {disk_before[1]} -> {disk_after[1]} B")  # fmt: skip
        assert not gone & after, gone & after
        assert ours.current | theirs.current <= after

        # The second workspace still builds with nothing rebuilt, and so does the first. Past
        # images_warn_gb, a build that changed nothing adds no image and says nothing of sizes.
        warned = "note: espdock's images on this engine take up to"
        for root in (second, first):
            again = espdock("build", cwd=root, env={**env, "ESPDOCK_IMAGES_WARN_GB": "0.001"})
            assert again.returncode == 0, again.stdout[-3000:] + again.stderr
            assert "cache miss" not in again.stdout, again.stdout[-3000:]
            assert warned not in again.stdout, again.stdout[-3000:]

        # Every recorded workspace: the first's images the second uses stay, listed once, for the
        # second's use of them (the records' order on disk differs from machine to machine).
        every = espdock("prune", "--all-workspaces", "--keep", "0", "--dry-run", cwd=second, env=env)
        assert every.returncode == 0, every.stdout + every.stderr
        for tag in shared:
            assert every.stdout.count(f"kept {tag} (") == 1, every.stdout
            assert f"kept {tag} (used by the current inputs)" in every.stdout, every.stdout

        # prune_auto: a build of new inputs removes what the ones before used; past
        # images_warn_gb it says so, once.
        generation(first, run, 4)
        settings = {"ESPDOCK_PRUNE_AUTO": "true", "ESPDOCK_PRUNE_KEEP": "0", "ESPDOCK_IMAGES_WARN_GB": "0.001"}
        auto = espdock("build", cwd=first, env={**env, **settings})
        assert auto.returncode == 0, auto.stdout[-3000:] + auto.stderr
        assert "prune_auto: removed 3 images no longer used" in auto.stdout, auto.stdout[-3000:]
        assert auto.stdout.count(warned) == 1, auto.stdout[-3000:]
        assert not ours.current & on_engine(engine) and theirs.current <= on_engine(engine)

        # A removed workspace protects nothing and keeps nothing: a prune says so, and a prune of
        # every workspace removes all its images and its record.
        shutil.rmtree(second)
        hinted = espdock("prune", "--keep", "0", "--dry-run", cwd=first, env=env)
        assert f"1 workspace(s) built here are gone ({second}): espdock prune --all-workspaces" in hinted.stdout
        # From anywhere: the clean-up after removing one's workspaces was refused outside of one.
        outside = espdock("prune", "--all-workspaces", "--keep", "0", "--dry-run", cwd=tmp_path, env=env)
        assert outside.returncode == 0 and "its workspace is gone)" in outside.stdout, outside.stdout + outside.stderr
        every = espdock("prune", "--all-workspaces", "--keep", "0", cwd=first, env=env)
        assert every.returncode == 0, every.stdout + every.stderr
        for tag in theirs.current:
            assert f"removed {tag} (" in every.stdout and tag not in on_engine(engine), every.stdout
        assert "its workspace is gone)" in every.stdout, every.stdout
        # Its name's :latest too, which no build makes again (it kept the image, unsaid, for ever).
        latest = f"espdock/prune-b-{run}:latest"
        assert f"removed {latest} (" in every.stdout and latest not in on_engine(engine), every.stdout
        assert list(recorded(state)) == [str(first)]
        assert recorded(state)[str(first)].current <= on_engine(engine)
    finally:
        records = recorded(state)
        tags = {i.tag for record in records.values() for i in record.images}
        tags |= {f"espdock/prune-{side}-{run}:latest" for side in "ab"}
        left = tags & on_engine(engine) | {t for t in tags if t.endswith(":latest")}
        subprocess.run(["docker", "rmi", *sorted(left)], capture_output=True, check=False)
