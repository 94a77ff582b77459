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
from espdock.layout import home_dir

DEFAULT = "default"
# How ENV sets TLS up for the CLI's default context; a context of its own replaces them all.
TLS_VARIABLES = ("DOCKER_TLS", "DOCKER_TLS_VERIFY", "DOCKER_CERT_PATH")
# The CLI's TLS files in DOCKER_CERT_PATH, or in a context's TLS dir: its CA, its certificate, its key.
TLS_FILES = ("ca.pem", "cert.pem", "key.pem")


def config_dir(env: Mapping[str, str]) -> Path:
    """The Docker CLI's configuration directory."""
    return Path(env.get("DOCKER_CONFIG") or home_dir(env) / ".docker")


def is_context_tls(path: str | Path, env: Mapping[str, str]) -> bool:
    """Whether PATH is a context's TLS dir in the CLI's store (engine_env names it in
    DOCKER_CERT_PATH), which needs no ca.pem, unlike a DOCKER_CERT_PATH of the user's."""
    return Path(path).is_relative_to(config_dir(env) / "contexts" / "tls")


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


# The Docker CLI's `proxies` fields (config.json) and the variables `docker run` and `docker build`
# set from them (docker/cli's ParseProxyConfig), each in upper and lower case.
_PROXY_FIELDS = (
    ("httpProxy", "HTTP_PROXY"),
    ("httpsProxy", "HTTPS_PROXY"),
    ("noProxy", "NO_PROXY"),
    ("ftpProxy", "FTP_PROXY"),
    ("allProxy", "ALL_PROXY"),
)


def run_proxies(env: Mapping[str, str], host: str) -> dict[str, str]:
    """The proxy variables `docker run` gives a container on the engine at HOST: the CLI config's
    `proxies` entry for HOST, else its "default" one. Not the shell's HTTP_PROXY, which the CLI
    does not pass either (a proxy on the host's 127.0.0.1 is no proxy inside a container)."""
    try:
        proxies = json.loads((config_dir(env) / "config.json").read_text()).get("proxies")
    except (OSError, ValueError, AttributeError):
        return {}
    chosen = proxies.get(host if host in proxies else DEFAULT) if isinstance(proxies, dict) else None
    if not isinstance(chosen, dict):
        return {}
    found = {}
    for field, variable in _PROXY_FIELDS:
        if isinstance(value := chosen.get(field), str) and value:
            found[variable] = found[variable.lower()] = value
    return found


# The Docker CLI's settings for its user's own commands that espdock's calls (its image builds, its
# containers) must not take: its images are built for the engine's platform and run from local
# tags. DOCKER_DEFAULT_PLATFORM (an Apple silicon habit) ran them as another platform ("Unable to
# find image"), DOCKER_BUILDKIT=0 built them without BuildKit (no secrets or cache mounts: every
# build failed), DOCKER_CONTENT_TRUST had each run ask a notary server to sign a local image.
NOT_FOR_ESPDOCK = ("DOCKER_DEFAULT_PLATFORM", "DOCKER_BUILDKIT", "DOCKER_CONTENT_TRUST", "DOCKER_CONTENT_TRUST_SERVER")


def resolve(env: Mapping[str, str]) -> tuple[dict[str, str], dict[str, str], tuple[str, str] | None]:
    """(engine_env(ENV), cli_env(ENV) for espdock's own calls (without NOT_FOR_ESPDOCK), selected(ENV)),
    reading the CLI's configuration once."""
    chosen = selected(env)
    own = {key: value for key, value in _cli_env(env, chosen).items() if key not in NOT_FOR_ESPDOCK}
    if chosen is None and env.get("DOCKER_HOST"):
        # Where `docker` is Podman's (podman-docker, Fedora's and RHEL's), it reads CONTAINER_HOST,
        # not DOCKER_HOST: `espdock run` and `shell` ran on another engine than the build's.
        own["CONTAINER_HOST"] = env["DOCKER_HOST"]
    return _engine_env(env, chosen), own, chosen


def engine_env(env: Mapping[str, str]) -> dict[str, str]:
    """ENV with DOCKER_HOST, and its TLS settings, of the context the CLI uses; ENV as it is when
    that is the default. For the SDK, which knows no contexts. Raises ConfigError for a context
    the CLI does not have."""
    return _engine_env(env, selected(env))


def _engine_env(env: Mapping[str, str], chosen: tuple[str, str] | None) -> dict[str, str]:
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
    # The context decides TLS, as for the CLI, which then reads none of the variables for it.
    resolved = {key: value for key, value in env.items() if key not in TLS_VARIABLES}
    resolved["DOCKER_HOST"] = host
    tls = store / "tls" / digest / "docker"
    # As docker/cli's Endpoint.tlsConfig: TLS wherever the context holds any of the three files
    # (a CA alone is an engine that asks no client certificate) or skips verification, which
    # then needs none of them. A socket or an ssh endpoint never uses it.
    has_files = any((tls / name).is_file() for name in TLS_FILES)
    skip = endpoint.get("SkipTLSVerify") is True
    if (has_files or skip) and not host.startswith(("unix://", "npipe://", "fd://", "ssh://")):
        resolved["DOCKER_CERT_PATH"] = str(tls)
        resolved["DOCKER_TLS" if skip else "DOCKER_TLS_VERIFY"] = "1"  # DOCKER_TLS: without verification
    return resolved


def cli_env(env: Mapping[str, str]) -> dict[str, str]:
    """ENV for the docker CLI and compose: the context espdock uses pinned by its name, which
    they read as espdock does. Not engine_env's variables: the CLI wants a ca.pem in a
    DOCKER_CERT_PATH even where it verifies nothing, which a context skipping verification
    may not have."""
    return _cli_env(env, selected(env))


def _cli_env(env: Mapping[str, str], chosen: tuple[str, str] | None) -> dict[str, str]:
    return dict(env) if chosen is None else {**env, "DOCKER_CONTEXT": chosen[0]}
