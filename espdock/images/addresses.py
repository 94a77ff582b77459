"""Where the container engine is, as the docker CLI reads DOCKER_HOST, and what to tell a user
whose engine does not answer there: how to start it (Docker's service, rootless Docker's, Podman's,
a remote one), or why starting it would not help (a socket this user may not use, TLS, a port that
takes the connection and never answers)."""

from __future__ import annotations

import os
import re
import stat
from collections.abc import Mapping
from urllib.parse import urlsplit

from espdock.errors import ConfigError, EngineUnavailable

DEFAULT_SOCKET = "/var/run/docker.sock"
DEFAULT_HOST = f"unix://{DEFAULT_SOCKET}"
# The addresses docker/cli's ParseHost takes (npipe: Windows; fd: systemd's socket activation).
ENGINE_SCHEMES = ("unix", "tcp", "ssh", "npipe", "fd")

# OpenSSL's alerts for an engine that refused the client's certificate (none, or one its CA did not sign).
TLS_REFUSALS = ("ALERT_UNKNOWN_CA", "ALERT_CERTIFICATE_REQUIRED", "ALERT_BAD_CERTIFICATE", "ALERT_HANDSHAKE_FAILURE")
TLS_CUT = "EOF occurred in violation of protocol"  # Python's words for a TLS connection closed mid-exchange


def host_of(env: Mapping[str, str]) -> str:
    """The engine's address in ENV (as contexts.engine_env gives it): DOCKER_HOST, or the default socket."""
    return env.get("DOCKER_HOST") or DEFAULT_HOST


def as_the_cli_reads(env: dict[str, str]) -> dict[str, str]:
    """ENV with its DOCKER_HOST as the docker CLI reads it (docker/cli's opts.ParseHost), which
    espdock runs on the same value: `unix://` is the default socket, `tcp://HOST` port 2375, and
    `HOST:PORT` without a scheme tcp://; the SDK took the first as "[Errno 22] Invalid argument"
    and the second as "port is required", each said as no engine running. A path without
    `unix://`, which the CLI misreads as a TCP address, is refused."""
    host = (env.get("DOCKER_HOST") or "").strip()
    if not host:
        return env
    if host.startswith("unix:") and not host.startswith("unix://"):
        # unix:/var/run/docker.sock: read below as a relative path (unix: a directory of it).
        path = host.removeprefix("unix:")
        whole = _whole(path) if path.startswith((".", "~")) else "/" + path.lstrip("/")
        raise ConfigError(
            f"DOCKER_HOST {host}: a socket's address is unix:// and its path", f"Set DOCKER_HOST=unix://{whole}"
        )
    if host.startswith("unix:///") and len(host) > len("unix:///") and host.endswith("/"):
        raise ConfigError(
            f"DOCKER_HOST {host}: a socket's path ends in its name, not a slash",
            f"Set DOCKER_HOST={host.rstrip('/')}",
        )
    if "://" not in host:
        # A path: absolute, relative (`run/user/1000/docker.sock`, which the CLI takes for tcp://run),
        # or a socket's file name.
        head, slash, _ = host.partition("/")
        if host.startswith(("/", ".", "~")) or host.endswith(".sock") or (slash and ":" not in head):
            raise ConfigError(
                f"DOCKER_HOST {host}: a socket's path needs its scheme, unix://{_whole(host)}",
                f"Set DOCKER_HOST=unix://{_whole(host)} (an engine is unix:///path/docker.sock, tcp://HOST:PORT or "
                "ssh://USER@HOST).",
            )
        host = f"tcp://{host}"
    if host == "unix://":
        host = f"unix://{DEFAULT_SOCKET}"
    elif host.startswith("unix://") and not host.startswith("unix:///"):
        # The CLI and the SDK take it from the directory each command runs in: espdock runs from
        # any directory of a workspace, Compose from its root. Most often a slash left out.
        raise ConfigError(
            f"DOCKER_HOST {host}: a socket's path must be whole (from /), not relative to wherever a command runs",
            f"Set DOCKER_HOST=unix://{_whole(host.removeprefix('unix://'))}",
        )
    elif host.startswith(("fd://", "npipe://")):
        # The SDK said "fd protocol is not implemented", and espdock to start an engine there.
        kind = "a daemon's own listening socket (systemd's)" if host.startswith("fd://") else "Windows' named pipe"
        raise ConfigError(
            f"DOCKER_HOST {host}: {kind}, which a client on Linux does not reach",
            f"Set DOCKER_HOST to the engine's socket (unix://{DEFAULT_SOCKET}), or to tcp://HOST:PORT or ssh://USER@HOST.",
        )
    elif host.startswith(("tcp://", "ssh://")):
        parts = urlsplit(host)
        if host.startswith("ssh://") and not parts.hostname:
            raise ConfigError(f"DOCKER_HOST {host}: names no host", "Set DOCKER_HOST=ssh://USER@HOST.")
        try:
            port = parts.port
        except ValueError:
            raise ConfigError(f"DOCKER_HOST {host}: its port is not a number") from None
        if host.startswith("ssh://") and ":" in (parts.hostname or ""):
            # The SDK's ssh transport splits host from port at the first colon.
            raise ConfigError(
                f"DOCKER_HOST {host}: espdock's Docker library cannot reach an ssh engine at an IPv6 address",
                "Name the host in your ssh config (`Host engine` with `HostName " + str(parts.hostname) + "`) and "
                "set DOCKER_HOST=ssh://USER@engine.",
            )
        if port is None and host.startswith("tcp://"):
            name = parts.hostname or "localhost"
            host = f"tcp://{f'[{name}]' if ':' in name else name}:2375{parts.path}"
    return {**env, "DOCKER_HOST": host}


def _whole(path: str) -> str:
    """PATH, a socket's, from /: a slash left out (var/run/docker.sock) where that names a socket,
    else from the current directory (or home, for ~)."""
    if not path.startswith(("/", ".", "~")) and is_socket(f"/{path}"):
        return f"/{path}"
    return os.path.abspath(os.path.expanduser(path))


def local_socket(env: Mapping[str, str]) -> str | None:
    """The engine's unix socket path, or None when DOCKER_HOST names another kind of host."""
    host = host_of(env)
    return host.removeprefix("unix://") if host.startswith("unix://") else None


def is_socket(path: str) -> bool:
    try:
        return stat.S_ISSOCK(os.stat(path).st_mode)
    except OSError:
        return False


def is_podman(where: str, podman: bool | None) -> bool:
    """Whether the engine at WHERE is Podman: what /_ping said (PODMAN), and before it answered,
    its address (Podman's sockets are /run/podman/podman.sock and $XDG_RUNTIME_DIR/podman/podman.sock)."""
    return podman if podman is not None else "podman" in where


def how_to_start(env: Mapping[str, str], context: tuple[str, str] | None, podman: bool | None) -> str:
    """How a user starts the engine ENV (contexts.engine_env's) names: Docker's service, rootless
    Docker's, Podman's API service (PODMAN: what /_ping said, None before it answered), or the
    remote engine, by the CONTEXT (contexts.selected's) that chose it when one did."""
    where = host_of(env)
    if is_podman(where, podman):
        return (
            "Start Podman's API service (`systemctl --user start podman.socket`, as root "
            "`systemctl start podman.socket`, or `podman system service --time=0`: without it, the "
            "service ends after 5 s with no call, in the middle of a build)"
        )
    if context is not None:
        return f'Start the engine of the Docker context "{context[0]}" ({context[1]}, at {where})'
    if where.startswith("ssh://"):
        # An ssh that could not log in said so above; starting an engine would not mend it.
        parts = urlsplit(where)
        destination = f"{parts.username}@{parts.hostname}" if parts.username else str(parts.hostname)
        login = f"ssh -p {parts.port} {destination}" if parts.port else f"ssh {destination}"
        return (
            f"Check that `{login}` logs in without a question (ssh says why where it does not), and that the "
            "engine runs there"
        )
    socket = local_socket(env)
    if socket is None:
        return f"Start the engine at {where}"
    if socket == DEFAULT_SOCKET:
        # A user's own engine running beside no system one (rootless Docker, Podman): name it.
        runtime = env.get("XDG_RUNTIME_DIR") or f"/run/user/{os.getuid()}"
        own = [p for p in (f"{runtime}/docker.sock", f"{runtime}/podman/podman.sock") if is_socket(p)]
        if own:
            return f"Start Docker (`sudo systemctl start docker`), or use your own engine: DOCKER_HOST=unix://{own[0]}"
        return "Start Docker (`sudo systemctl start docker`)"
    return f"Start the daemon of {socket} (rootless Docker: `systemctl --user start docker`)"


def not_a_socket(path: str) -> str | None:
    """What PATH is where it is there and no socket ("a regular file", "a directory"), else None."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return None
    if stat.S_ISSOCK(mode):
        return None
    return "a directory" if stat.S_ISDIR(mode) else "a regular file" if stat.S_ISREG(mode) else "a special file"


def unreachable(what: str, exc: Exception) -> EngineUnavailable:
    """WHAT ("no Docker engine answers ..."), why, and for a TLS failure, which starting the
    engine would not mend, what to do."""
    text = str(exc)
    if "Permission denied" in text:
        # The engine runs: starting it, the usual hint, would not help.
        return EngineUnavailable(
            f"{what}: permission denied on the engine's socket",
            "The engine runs, but this user may not use its socket: join the group that owns it (the docker "
            "group, for Docker's: `sudo usermod -aG docker $USER`, then log in again), or use an engine of your "
            "own (rootless Docker or Podman, through DOCKER_HOST).",
        )
    if "No such file or directory" in text or "Connection refused" in text:
        return EngineUnavailable(f"{what}: nothing is listening there")
    if any(said in text for said in ("NameResolutionError", "Name or service not known", "name resolution")):
        return EngineUnavailable(f"{what}: its host name does not resolve")
    if "Read timed out" in text or text == "timed out":  # the SDK's, a local socket's
        # It took the connection: something listens there, which starting an engine would not mend.
        return EngineUnavailable(
            f"{what}: it took the connection and gave no answer in time",
            "Check DOCKER_HOST: what listens there is no engine (another service's port), or the engine there "
            "hangs (`docker version` against it hangs as well).",
        )
    tls = tls_failure(text)
    if tls is None:
        return EngineUnavailable(f"{what}: {text}")
    return EngineUnavailable(
        f"{what}: {tls}",
        "Give espdock the engine's CA and your certificate as the docker CLI takes them (`docker version` "
        "fails the same way): ca.pem, cert.pem and key.pem in DOCKER_CERT_PATH, or in the Docker context "
        "(`docker context inspect`); a context without a ca.pem checks against the system's CAs (SSL_CERT_FILE).",
    )


def tls_failure(text: str) -> str | None:
    """What went wrong, by TEXT (an exception's), where TLS failed between espdock and the engine."""
    # OpenSSL's words, out of the SDK's wrappings (urllib3's retries, requests' connection error).
    said = re.search(r"\[SSL: \w+\][^'\")(]*", text)
    openssl = said.group(0).strip() if said else text
    if "CERTIFICATE_VERIFY_FAILED" in text:
        return f"its TLS certificate is not signed by the CA espdock checks it against ({openssl})"
    if any(alert in text for alert in TLS_REFUSALS):
        return f"it refused espdock's TLS client certificate ({openssl})"
    if TLS_CUT in text:
        # TLS 1.3: the engine checks the client's certificate after the client is done, and its alert
        # may be lost as it closes the connection; espdock then sees only the end.
        return f"it ended the TLS connection, as an engine refusing espdock's TLS client certificate does ({TLS_CUT})"
    return None
