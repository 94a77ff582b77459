"""The engine the Docker CLI talks to, so that espdock, `docker` and `docker compose` use one.

DOCKER_HOST names it; without it, the CLI's context does: DOCKER_CONTEXT, else currentContext in
$DOCKER_CONFIG/config.json (~/.docker). Rootless Docker's setup tool, Docker Desktop and colima
select a context and leave DOCKER_HOST unset: espdock would otherwise build on the default socket's
engine while `docker compose up` ran on the context's, with its own (or no) images of the same tags.
Read from the CLI's own files (its context store), with no SDK and no `docker` process.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from pathlib import Path

from espdock.errors import ConfigError

DEFAULT = "default"


def config_dir(env: Mapping[str, str]) -> Path:
    """The Docker CLI's configuration directory."""
    return Path(env.get("DOCKER_CONFIG") or Path(env.get("HOME") or Path.home()) / ".docker")


def selected(env: Mapping[str, str]) -> tuple[str, str] | None:
    """The context the CLI uses in ENV and what chose it, or None when that is the default
    (DOCKER_HOST set, or no context chosen)."""
    if env.get("DOCKER_HOST"):
        return None
    if name := env.get("DOCKER_CONTEXT"):
        chosen = (name, "DOCKER_CONTEXT")
    else:
        path = config_dir(env) / "config.json"
        try:
            current = json.loads(path.read_text()).get("currentContext")
        except (OSError, ValueError, AttributeError):
            current = None  # the CLI warns and goes on with the default: so does espdock
        if not isinstance(current, str) or not current:
            return None
        chosen = (current, f"currentContext in {path}")
    return None if chosen[0] == DEFAULT else chosen


def engine_env(env: Mapping[str, str]) -> dict[str, str]:
    """ENV with DOCKER_HOST, and its TLS settings, of the context the CLI uses; ENV as it is when
    that is the default. Raises ConfigError for a context the CLI does not have."""
    chosen = selected(env)
    if chosen is None:
        return dict(env)
    name, source = chosen
    # The CLI's store keys a context by its name's SHA-256 (docker/cli's context store).
    digest = hashlib.sha256(name.encode()).hexdigest()
    store = config_dir(env) / "contexts"
    meta = store / "meta" / digest / "meta.json"
    try:
        endpoint = json.loads(meta.read_text())["Endpoints"]["docker"]
        host = str(endpoint["Host"])
    except FileNotFoundError:
        raise ConfigError(
            f'the Docker context "{name}" ({source}) does not exist: no {meta}',
            "`docker context ls` lists the contexts; `docker context use NAME` picks one "
            "(`default` for the local engine), or set DOCKER_HOST.",
        ) from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ConfigError(
            f'the Docker context "{name}" ({source}) cannot be read: {meta}: {exc}',
            f"Create it again (`docker context rm {name}`, then `docker context create`), or set DOCKER_HOST.",
        ) from None
    resolved = {**env, "DOCKER_HOST": host}
    tls = store / "tls" / digest / "docker"
    if (tls / "cert.pem").is_file() and (tls / "key.pem").is_file():
        resolved["DOCKER_CERT_PATH"] = str(tls)
        if endpoint.get("SkipTLSVerify") is True:
            resolved.pop("DOCKER_TLS_VERIFY", None)
        else:
            resolved["DOCKER_TLS_VERIFY"] = "1"
    return resolved
