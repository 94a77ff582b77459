"""A real OCI registry for tests and benchmarks: Debian's docker-registry (the distribution
registry) on a free loopback port, with htpasswd auth, and the engine login that goes with it."""

from __future__ import annotations

import base64
import json
import subprocess
import time
import urllib.error
import urllib.request
import uuid
from pathlib import Path

from tests.ports import free_port

USER, PASSWORD = "ci", "cache-" + uuid.uuid4().hex[:12]


class Registry:
    """The registry's config, password file and log in ROOT; its blobs in STORAGE (default
    ROOT/data), on PORT (default: a free one)."""

    def __init__(self, root: Path, port: int | None = None, storage: Path | None = None) -> None:
        self.root = root
        self.port = free_port() if port is None else port
        self.address = f"127.0.0.1:{self.port}"
        self.storage = storage or root / "data"
        root.mkdir(parents=True, exist_ok=True)
        self.storage.mkdir(parents=True, exist_ok=True)
        hashed = subprocess.run(["htpasswd", "-Bbn", USER, PASSWORD], capture_output=True, text=True, check=True)
        (root / "htpasswd").write_text(hashed.stdout)
        (root / "config.yml").write_text(
            "version: 0.1\nlog:\n  level: warn\n"
            f"storage:\n  filesystem:\n    rootdirectory: {self.storage}\n"
            f"http:\n  addr: {self.address}\n  secret: espdock-test\n"
            f"auth:\n  htpasswd:\n    realm: espdock-test\n    path: {root / 'htpasswd'}\n"
        )
        self.process: subprocess.Popen | None = None

    def start(self) -> None:
        log = open(self.root / "registry.log", "ab")  # closed with the process
        self.process = subprocess.Popen(
            ["docker-registry", "serve", str(self.root / "config.yml")], stdout=log, stderr=subprocess.STDOUT
        )
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            try:
                urllib.request.urlopen(f"http://{self.address}/v2/", timeout=1)
            except urllib.error.HTTPError as exc:
                if exc.code == 401:  # up, and asking for credentials
                    return
            except OSError:
                pass
            time.sleep(0.2)
        raise AssertionError(f"docker-registry did not start: {(self.root / 'registry.log').read_text()[-2000:]}")

    def stop(self) -> None:
        if self.process is not None:
            self.process.terminate()
            self.process.wait(timeout=30)
            self.process = None

    def tags(self, repository: str) -> list[str]:
        request = urllib.request.Request(f"http://{self.address}/v2/{repository}/tags/list")
        request.add_header("Authorization", "Basic " + base64.b64encode(f"{USER}:{PASSWORD}".encode()).decode())
        try:
            with urllib.request.urlopen(request, timeout=10) as response:
                return json.load(response).get("tags") or []
        except urllib.error.HTTPError as exc:
            if exc.code == 404:
                return []
            raise


def docker_config(where: Path, address: str, password: str) -> dict[str, str]:
    """A DOCKER_CONFIG as `docker login` leaves it: the engine's login, the only credentials espdock uses."""
    where.mkdir(parents=True, exist_ok=True)
    auth = base64.b64encode(f"{USER}:{password}".encode()).decode()
    (where / "config.json").write_text(json.dumps({"auths": {address: {"auth": auth}}}))
    return {"DOCKER_CONFIG": str(where)}
