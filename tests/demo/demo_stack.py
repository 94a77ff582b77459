"""The demo's compose stack for tests and the benchmark: a uniquely named project, always torn down.

Each DemoStack is its own compose project (own network, so its DDS traffic
never meets another demo's), with the UI on a free host port. The probe
(`demo_probe` in the runtime image) runs with `docker compose run` on the
stack's network to watch and poke the ROS graph.
"""

from __future__ import annotations

import json
import os
import random
import shutil
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Mapping
from pathlib import Path

from tests.ports import free_port

ROOT = Path(__file__).resolve().parents[2]
COMPOSE_FILE = ROOT / "compose.yaml"
SERVICES = ("camera_sim", "led_strip_sim", "qr_detector", "camera_ui", "demo")


class StackError(RuntimeError):
    """A compose command or the probe failed; the message carries its output."""


def docker_problem() -> str | None:
    """Why the Docker engine or Compose v2 cannot be used here, or None when both answer."""
    if shutil.which("docker") is None:
        return "the docker CLI is not on PATH (run `make setup`)"
    info = subprocess.run(
        ["docker", "info", "--format", "{{.ServerVersion}}"], capture_output=True, text=True, check=False
    )
    if info.returncode != 0:
        return f"no Docker engine answers (run `make setup` or `espdock setup`): {info.stderr.strip()[:300]}"
    compose = subprocess.run(["docker", "compose", "version"], capture_output=True, text=True, check=False)
    if compose.returncode != 0:
        return "`docker compose` (v2) is missing (run `espdock setup`)"
    return None


def build_image(env: Mapping[str, str] | None = None) -> None:
    """Build the demo's runtime image (espdock/demo:latest) as `make demo` does: `espdock build`
    makes it from ws/install, by key, with every other workspace's runtime image."""
    argv = [sys.executable, "-m", "espdock", "build", "--only", "ros"]
    result = subprocess.run(argv, cwd=ROOT, env=dict(env or os.environ), capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise StackError(f"building the demo image failed:\n{(result.stdout + result.stderr)[-3000:]}")


def probe_command() -> list[str]:
    """The probe service's entrypoint after tini (which a waiting container already has as PID 1)."""
    import yaml

    entrypoint = yaml.safe_load(COMPOSE_FILE.read_text())["services"]["probe"]["entrypoint"]
    return entrypoint[entrypoint.index("--") + 1 :]


class DemoStack:
    """One running demo: `up()`, then probes and HTTP calls, and always `down()`."""

    def __init__(self, name: str | None = None, **settings: str) -> None:
        self.project = name or f"espdock-test-{os.getpid()}-{random.randrange(16**6):06x}"
        self.port = free_port()
        self.prober: str | None = None  # a waiting probe container (keep_a_prober), else one per probe
        self.env = {
            **os.environ,
            "ESPDOCK_DEMO_PORT": str(self.port),
            "ESPDOCK_DEMO_BIND": "127.0.0.1",
            # Not the default domain: proves ROS_DOMAIN_ID reaches every node (and the probe).
            "ROS_DOMAIN_ID": str(random.randrange(1, 100)),
            **settings,
        }

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def compose(self, *args: str, timeout: float = 300, check: bool = True) -> subprocess.CompletedProcess:
        argv = [
            "docker",
            "compose",
            "-p",
            self.project,
            "-f",
            str(COMPOSE_FILE),
            "--project-directory",
            str(ROOT),
            *args,
        ]
        try:
            result = subprocess.run(argv, env=self.env, capture_output=True, text=True, timeout=timeout, check=False)
        except subprocess.TimeoutExpired as exc:
            raise StackError(f"`docker compose {' '.join(args)}` did not finish within {timeout:g} s") from exc
        if check and result.returncode != 0:
            raise StackError(
                f"`docker compose {' '.join(args)}` failed ({result.returncode}):\n"
                f"{(result.stdout + result.stderr)[-3000:]}"
            )
        return result

    def up(self, timeout: float = 180) -> None:
        """Start the demo and wait until the UI reports every node up and the camera online.

        The nodes' own word, not `up --wait`: Docker runs a container's first healthcheck only
        one interval (10 s) after its start, seconds after the nodes are up. Tests of Docker's
        verdict wait for it with `checked_health`."""
        self.compose("up", "-d", "demo", timeout=timeout + 30)
        self.wait_until(self.ready, timeout, "every node up and the camera online in the UI's /api/state")

    def ready(self) -> bool:
        try:
            state = self.state()
        except (OSError, StackError, ValueError):  # the UI not listening yet, or starting to
            return False
        nodes = state.get("nodes") or {}
        return bool(nodes) and all(node["state"] == "ok" for node in nodes.values()) and state["camera"]["online"]

    def down(self) -> None:
        self.compose("--profile", "*", "down", "-v", "--remove-orphans", "-t", "3", check=False, timeout=120)

    def logs(self, tail: int = 40) -> str:
        return self.compose("--profile", "*", "logs", "--no-color", "--tail", str(tail), check=False).stdout

    def keep_a_prober(self) -> None:
        """Start the probe service's container once, waiting, for `probe` to run its program in: each
        `compose run` of it creates, starts and removes a container (about 2 s on a loaded 2-core
        machine). `down` removes it with the project's other one-off containers."""
        # tini as PID 1, as in the service: a stop's SIGTERM ends the sleep at once.
        waiting = self.compose(
            "run", "-d", "--no-deps", "--entrypoint", "/usr/bin/tini --", "probe", "sleep", "infinity"
        )
        self.prober = waiting.stdout.strip().splitlines()[-1]

    def probe(self, *args: str, timeout: float = 120) -> dict:
        """Run `demo_probe ARGS` on the stack's network; its JSON answer."""
        if self.prober:
            # As the service's entrypoint runs it, in the waiting container (same image, network, environment).
            argv = ["docker", "exec", self.prober, *probe_command(), *args]
            try:
                result = subprocess.run(argv, capture_output=True, text=True, timeout=timeout + 60, check=False)
            except subprocess.TimeoutExpired as exc:
                raise StackError(f"demo_probe {' '.join(args)} did not finish within {timeout + 60:g} s") from exc
        else:
            result = self.compose("run", "--rm", "--no-deps", "-T", "probe", *args, timeout=timeout + 60, check=False)
        lines = result.stdout.strip().splitlines()
        if result.returncode != 0 or not lines:
            raise StackError(
                f"demo_probe {' '.join(args)} failed ({result.returncode}):\n"
                f"{result.stdout[-1500:]}\n{result.stderr[-2500:]}"
            )
        return json.loads(lines[-1])

    # Containers

    def container(self, service: str) -> str:
        cid = self.compose("ps", "-a", "-q", service).stdout.strip()
        if not cid:
            raise StackError(f"no container for {service}")
        return cid.splitlines()[0]

    def inspect(self, service: str) -> dict:
        out = subprocess.run(
            ["docker", "inspect", self.container(service)], capture_output=True, text=True, check=True
        ).stdout
        return json.loads(out)[0]

    def restart_count(self, service: str) -> int:
        return int(self.inspect(service)["RestartCount"])

    def restart_counts(self) -> dict[str, int]:
        """How often Docker restarted each service's container (its restart policy, not a `compose start`)."""
        ids = self.compose("ps", "-a", "-q").stdout.split()
        out = subprocess.run(["docker", "inspect", *ids], capture_output=True, text=True, check=True).stdout
        return {c["Config"]["Labels"]["com.docker.compose.service"]: int(c["RestartCount"]) for c in json.loads(out)}

    def health(self, service: str) -> str:
        state = self.inspect(service)["State"]
        return state.get("Health", {}).get("Status") or state["Status"]

    def checked_health(self, service: str, timeout: float = 30) -> str:
        """Docker's verdict on SERVICE once its healthcheck has run (it says "starting" until the
        first check, one interval after the container started)."""
        return self.wait_until(
            lambda: (status := self.health(service)) != "starting" and status, timeout, f"{service}'s first healthcheck"
        )

    def crash(self, service: str) -> None:
        """Kill SERVICE's node with SIGKILL from inside, as a crash would (`docker kill` counts as a
        deliberate stop, after which Docker does not restart a container)."""
        # The container ends with its node (tini exits with its status), the exec's answer with it.
        self._signal_all(service, "KILL", check=False)

    def freeze(self, service: str) -> None:
        """Stop SERVICE's processes where they stand (SIGSTOP), leaving the container running: a
        node that is there but does not answer. Not `docker pause`: the cgroup freezer gives up
        with "unable to freeze" when the machine is busy, which signals never do."""
        self._signal_all(service, "STOP")

    def thaw(self, service: str) -> None:
        self._signal_all(service, "CONT")

    def _signal_all(self, service: str, signal: str, check: bool = True) -> None:
        """SIGNAL to every process in SERVICE's container but PID 1 (tini) and the shell sending it (kill -1)."""
        subprocess.run(
            ["docker", "exec", self.container(service), "sh", "-c", f"kill -{signal} -1"],
            capture_output=True,
            check=check,
        )

    def wait_until(self, condition, timeout: float, what: str, interval: float = 0.5):
        deadline = time.monotonic() + timeout
        while True:
            value = condition()
            if value:
                return value
            if time.monotonic() > deadline:
                raise StackError(f"{what}: not within {timeout:g} s")
            time.sleep(interval)

    # The UI over HTTP, from the host

    def http(
        self, path: str, data: bytes | None = None, headers: Mapping[str, str] | None = None, timeout: float = 10
    ) -> tuple[int, bytes, str]:
        """(status, body, content type) of a request to the UI."""
        request = urllib.request.Request(self.url + path, data=data, headers=dict(headers or {}))
        try:
            with urllib.request.urlopen(request, timeout=timeout) as response:
                return response.status, response.read(), response.headers.get("Content-Type", "")
        except urllib.error.HTTPError as exc:
            return exc.code, exc.read(), exc.headers.get("Content-Type", "")

    def state(self) -> dict:
        status, body, _ = self.http("/api/state")
        if status != 200:
            raise StackError(f"/api/state answered {status}")
        return json.loads(body)

    def post_settings(self, **fields: int | str) -> tuple[int, dict]:
        """POST the settings form as the page's script does; (status, JSON answer)."""
        body = "&".join(f"{k}={v}" for k, v in fields.items()).encode()
        status, data, _ = self.http(
            "/config", body, {"Content-Type": "application/x-www-form-urlencoded", "Accept": "application/json"}
        )
        return status, json.loads(data)
