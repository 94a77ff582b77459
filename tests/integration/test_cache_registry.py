"""A cache registry shared by machines: keyed images built once, pulled everywhere else.

Against a real OCI registry: Debian's docker-registry (the distribution registry) on a
loopback port with htpasswd auth, started here, whose blobs outlive the run (see `registry`).
A second machine is a second clone of the workspace on an engine that lost espdock's images.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import tempfile
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from espdock.config import Config, resolve_ca_bundle
from tests.conftest import REPO, espdock, python_workspace, remove_images_built_from
from tests.idf_contract_double.build import use_double
from tests.ports import free_port, port_is_free
from tests.registry_server import PASSWORD, Registry, docker_config

pytestmark = [pytest.mark.engine, pytest.mark.slow]


# The engine remembers which layers it pushed to which registry (by host and port) and skips
# those the registry still has, as with a CI cache registry that outlives its jobs. So the
# registry keeps its port and its blobs between runs: a re-run pushes these tests' new
# manifests, not 1.4 GB of unchanged layers again. If the port is taken: a fresh one.
KEPT_PORT = 45123
KEPT_STORAGE_LIMIT = 4 << 30


@pytest.fixture(scope="module")
def registry(tmp_path_factory) -> Iterator[Registry]:
    assert shutil.which("docker-registry") and shutil.which("htpasswd"), "run tests/install-system-deps.sh"
    here = tmp_path_factory.mktemp("registry")
    if port_is_free(KEPT_PORT):
        storage = Path(tempfile.gettempdir()) / "espdock-test-registry"
        if tree_size(storage) > KEPT_STORAGE_LIMIT:  # images edited many times over: start again
            shutil.rmtree(storage)
        server = Registry(here, KEPT_PORT, storage)
    else:
        server = Registry(here)
    server.start()
    yield server
    server.stop()


@pytest.fixture(scope="module")
def origin(tmp_path_factory, engine) -> Iterator[tuple[Path, dict[str, str]]]:
    """Workspace sources with a Python package and firmware; comments unique to this run give it
    ROS and micro-ROS images no other test has (these tests remove them while other pytest
    workers build)."""
    root = python_workspace(tmp_path_factory.mktemp("cache") / "origin")
    shutil.copy2(REPO / "Dockerfile.idf", root / "Dockerfile.idf")
    shutil.copytree(REPO / "firmware", root / "firmware")
    shutil.rmtree(root / "firmware" / "camera_node")  # one app, one micro-ROS image: enough here
    double_env = use_double(engine, resolve_ca_bundle(Config(), os.environ), lambda line: None, root)
    run = uuid.uuid4().hex
    for dockerfile in (root / "Dockerfile.ros", root / "Dockerfile.idf"):
        dockerfile.write_text(dockerfile.read_text() + f"# cache test {run}\n")
    yield root, double_env
    remove_images_built_from(root / "Dockerfile.ros", root / "Dockerfile.idf")


def machine(origin: Path, where: Path) -> Path:
    """A fresh clone of the workspace: sources only, no build, install or log trees."""
    shutil.copytree(origin, where)
    return where


def registry_env(double_env: dict[str, str], registry: Registry, login: Path, password: str = PASSWORD) -> dict:
    """The double's settings, the cache registry, and an engine login for it with PASSWORD."""
    env = {**double_env, "ESPDOCK_CACHE_REGISTRY": registry.address}
    return env | docker_config(login, registry.address, password)


# The tests after the first are about the micro-ROS image alone: colcon has nothing to say there.
FIRMWARE = ("--only", "firmware")


def build(root: Path, env: dict[str, str], *options: str) -> tuple[subprocess.CompletedProcess, dict]:
    report = root / "report.json"
    result = espdock("build", "--report", str(report), *options, cwd=root, env=env)
    return result, json.loads(report.read_text()) if report.is_file() else {}


def image_outcomes(report: dict) -> dict[str, str]:
    return {s["step"]: s["outcome"] for s in report.get("steps", []) if s["step"].startswith("image")}


def keyed_tags(report: dict) -> list[str]:
    return sorted(report["manifest"]["images"])


def remove_images(tags: list[str]) -> None:
    subprocess.run(["docker", "rmi", "-f", *tags], capture_output=True, check=False)


def test_a_second_machine_pulls_every_keyed_image_and_builds_none(registry, origin, tmp_path):
    source, double_env = origin
    env = registry_env(double_env, registry, tmp_path / "docker")

    first, report = build(machine(source, tmp_path / "one"), env, "--push-cache")
    assert first.returncode == 0, first.stdout[-4000:] + first.stderr
    tags = keyed_tags(report)
    assert len(tags) >= 2, tags  # the ROS build image and the firmware's micro-ROS image
    for tag in tags:
        repository, key = tag.rsplit(":", 1)
        assert key in registry.tags(repository), f"{tag} was not pushed"

    built_labels = {tag: image_labels(tag) for tag in tags}
    remove_images(tags)  # the second machine has none of them
    second, report = build(machine(source, tmp_path / "two"), env)
    assert second.returncode == 0, second.stdout[-4000:] + second.stderr
    outcomes = image_outcomes(report)
    assert outcomes and set(outcomes.values()) == {"pulled"}, outcomes
    assert "pulled" in second.stdout
    for tag in tags:
        labels = subprocess.run(
            ["docker", "image", "inspect", "-f", "{{json .Config.Labels}}", tag],
            capture_output=True,
            text=True,
            check=False,
        )
        assert labels.returncode == 0, f"{tag} is not on the second machine"
        assert json.loads(labels.stdout) == built_labels[tag], "labels (key, inputs, package set) travel along"


def image_labels(tag: str) -> dict[str, str]:
    inspect = ["docker", "image", "inspect", "-f", "{{json .Config.Labels}}", tag]
    return json.loads(subprocess.run(inspect, capture_output=True, text=True, check=True).stdout)


def micro_ros_tag(report: dict) -> str:
    (tag,) = [t for t in keyed_tags(report) if "micro-ros" in t]
    return tag


def test_a_silent_registry_is_a_warning_and_a_local_build(registry, origin, tmp_path):
    source, double_env = origin
    root = machine(source, tmp_path / "ws")
    env = {**double_env, "ESPDOCK_CACHE_REGISTRY": f"127.0.0.1:{free_port()}"}
    first, report = build(root, env, *FIRMWARE)
    assert first.returncode == 0, first.stdout[-4000:] + first.stderr
    tag = micro_ros_tag(report)
    remove_images([tag])
    again, report = build(machine(source, tmp_path / "ws2"), env, *FIRMWARE)
    assert again.returncode == 0, again.stdout[-4000:] + again.stderr
    assert "did not answer" in again.stdout and "building locally" in again.stdout
    assert "built" in image_outcomes(report).values()
    # Asked to publish the cache, the build fails at its end, and its report says why: it
    # passed before, its warning cut short in the SDK's URL before the engine's reason.
    pushed, report = build(root, env, *FIRMWARE, "--push-cache")
    assert pushed.returncode == 2, pushed.stdout[-4000:] + pushed.stderr
    assert report["outcome"] == "failed" and "1 image(s) not pushed to 127.0.0.1:" in report["error"], report
    assert "connection refused" in report["error"], report["error"]


def test_wrong_credentials_are_a_clear_error(registry, origin, tmp_path):
    source, double_env = origin
    good = registry_env(double_env, registry, tmp_path / "good")
    ok, report = build(machine(source, tmp_path / "ws"), good, *FIRMWARE)
    assert ok.returncode == 0, ok.stdout[-4000:] + ok.stderr
    remove_images([micro_ros_tag(report)])
    bad = registry_env(double_env, registry, tmp_path / "bad", "not-the-password")
    denied, _ = build(machine(source, tmp_path / "ws2"), bad, *FIRMWARE)
    assert denied.returncode == 2, denied.stdout[-3000:] + denied.stderr
    assert "refused the engine's credentials" in denied.stderr and f"docker login 127.0.0.1:{registry.port}" in (
        denied.stderr
    )
    assert "Traceback" not in denied.stderr
    assert "not-the-password" not in denied.stdout + denied.stderr


def test_an_image_with_the_wrong_key_label_is_rejected(registry, origin, tmp_path):
    source, double_env = origin
    env = registry_env(double_env, registry, tmp_path / "docker")
    first, report = build(machine(source, tmp_path / "ws"), env, *FIRMWARE)
    assert first.returncode == 0, first.stdout[-4000:] + first.stderr
    tag = micro_ros_tag(report)
    # Someone pushes a different image under that name and key.
    impostor = f"{registry.address}/{tag}"
    context = tmp_path / "impostor"
    context.mkdir()
    (context / "Dockerfile").write_text("FROM debian:bookworm-slim\nLABEL io.espdock.key=0000not-this-key\n")
    subprocess.run(["docker", "build", "-q", "-t", impostor, str(context)], check=True, capture_output=True)
    pushed = subprocess.run(
        ["docker", "--config", env["DOCKER_CONFIG"], "push", impostor], capture_output=True, text=True, check=False
    )
    assert pushed.returncode == 0, pushed.stderr
    remove_images([tag, impostor])

    again, report = build(machine(source, tmp_path / "ws2"), env, *FIRMWARE)
    assert again.returncode == 0, again.stdout[-4000:] + again.stderr
    assert "rejected" in again.stdout
    assert image_outcomes(report)[f"image {tag.split(':')[0]}"] == "built"
    inspect = subprocess.run(
        ["docker", "image", "inspect", "-f", "{{index .Config.Labels \"io.espdock.key\"}}", tag],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    assert inspect.stdout.strip().startswith(tag.rsplit(":", 1)[1]), "the impostor took the key's name"


def tree_size(top: Path) -> int:
    return sum(path.stat().st_size for path in top.rglob("*") if path.is_file())
