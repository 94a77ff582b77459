"""The Docker SDK as engine.py uses it: imported on first use, without paramiko unless an
ssh:// engine needs it, and made to reach engines as the docker CLI does where the SDK alone
does not (an ssh engine's connections, a TLS engine's CA)."""

from __future__ import annotations

import importlib
import os
import select
import sys
import warnings
from collections.abc import Mapping
from contextlib import suppress
from typing import Any

from espdock import interrupts
from espdock.errors import ConfigError
from espdock.images import contexts


class _Lazy:
    """A module imported on first use (docker, requests)."""

    def __init__(self, *names: str) -> None:
        self._names = names

    def __getattr__(self, attribute: str) -> Any:
        # Held: a Ctrl-C in the middle of importing the SDK leaves urllib3 half-initialised in
        # sys.modules, and the cleanup that follows (which needs the SDK) then fails.
        with interrupts.held():
            if self._names[0] == "docker" and not _ssh_engines and "docker" not in sys.modules:
                return getattr(_sdk_without_ssh(), attribute)
            for name in self._names[1:]:
                importlib.import_module(name)
            return getattr(importlib.import_module(self._names[0]), attribute)


docker = _Lazy("docker", "docker.errors")
# The SDK's note, at each registry call, that a credential helper the Docker CLI's config names
# is missing: the call's own error says it, where it matters (a registry that needs the login).
warnings.filterwarnings("ignore", message="docker-credential-", category=UserWarning)
requests = _Lazy("requests", "requests.exceptions")

# Whether an ssh:// engine is to be reached: only it needs the SDK's ssh adapter.
_ssh_engines = False


def need_ssh() -> None:
    """Let the SDK, when first imported, bring its ssh adapter (and paramiko) along: call it
    before the first use of `docker` wherever an ssh:// engine is to be reached."""
    global _ssh_engines  # noqa: PLW0603 (read by the SDK's first import, see _sdk_without_ssh)
    _ssh_engines = True


def _sdk_without_ssh() -> Any:
    """The Docker SDK, imported without paramiko: its ssh adapter's module imports it whenever it
    is installed (0.1 s: a no-change build on a TCP engine took 0.41 s with it, 0.29 s without),
    in a try that leaves the adapter out when that fails. Should a later SDK import it outright,
    it is imported with it."""
    blocked = "paramiko" not in sys.modules
    if blocked:
        sys.modules["paramiko"] = None  # type: ignore[assignment]  # import paramiko: ImportError
    try:
        importlib.import_module("docker.errors")
        return importlib.import_module("docker")
    except ImportError:
        if not blocked:
            raise
        sys.modules.pop("paramiko", None)
        blocked = False
        importlib.import_module("docker.errors")
        return importlib.import_module("docker")
    finally:
        if blocked:
            sys.modules.pop("paramiko", None)


def client(env: Mapping[str, str], timeout: float, first: float | None = None) -> Any:
    """The SDK's client of the engine ENV names (DOCKER_HOST and the TLS variables): TIMEOUT for
    each answer, FIRST (default TIMEOUT) for the one it asks as it is made."""
    ssh = env.get("DOCKER_HOST", "").startswith("ssh://")
    # The SDK asks the engine its API version as the client is made; given one, it asks nothing,
    # and espdock asks once the client reaches the engine as `docker` does. Through `docker`, so
    # that the SDK's first import leaves paramiko out unless need_ssh was called.
    minimum = docker.constants.MINIMUM_DOCKER_API_VERSION
    if ssh:
        # Through the ssh command, as `docker` does (the user's ssh config, agent and known
        # hosts), not paramiko's own client.
        made = docker.from_env(environment=env, timeout=timeout, use_ssh_client=True, version=minimum)
        _reuse_ssh_connections(made.api)
    else:
        host = env.get("DOCKER_HOST") or None
        made = docker.DockerClient(base_url=host, tls=_tls(env) or False, timeout=timeout, version=minimum)
        _keep_engine_ca(made.api)  # TLS: an ssh engine has none
        if _loopback(host):
            # requests took HTTP_PROXY for it (NO_PROXY matching only the very name), and the proxy
            # answered "403 Forbidden" for the engine; Go's proxy rules, `docker`'s, never proxy loopback.
            made.api.trust_env = False
    # An address that takes the connection and never answers (another service's port) kept
    # espdock silent for the whole operation timeout, two minutes.
    made.api.timeout = timeout if first is None else first
    try:
        made.api._version = made.api._retrieve_server_version()  # what version="auto" does
    finally:
        made.api.timeout = timeout
    return made


def followed_logs(container: Any) -> Any:
    """CONTAINER's output as it comes (`docker logs -f`) through the SDK, its answer awaited as long
    as the container is silent. Podman 4.3 (Debian bookworm's) sends that answer only with the first
    output: a colcon build silent for the client's two minutes ended as "did not answer", its
    container running on. Connecting still times out; once the answer starts, the SDK itself reads
    the stream without one."""
    api = container.client.api
    kept = api.timeout
    api.timeout = (kept, None)  # requests' (connect, read)
    try:
        return container.logs(stream=True, follow=True)
    finally:
        api.timeout = kept


def _loopback(host: str | None) -> bool:
    """Whether the engine address HOST (tcp://H:P) is this machine's loopback."""
    import ipaddress
    from urllib.parse import urlsplit

    if not host or not host.startswith(("tcp://", "http://", "https://")):
        return False
    name = urlsplit(host).hostname or ""
    if name == "localhost":
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False


def _tls(env: Mapping[str, str]) -> Any | None:
    """The TLS settings ENV gives the docker CLI (and compose), None for none. The SDK reads ENV
    otherwise: it ignores DOCKER_TLS (TLS without verification), takes a DOCKER_CERT_PATH alone
    for TLS, and refuses one without cert.pem and key.pem (an engine that asks for no client
    certificate, as `dockerd --tls` without --tlsverify), where the CLI goes without one."""
    verify = bool(env.get("DOCKER_TLS_VERIFY"))
    if not (verify or env.get("DOCKER_TLS")):
        return None
    where = env.get("DOCKER_CERT_PATH") or str(contexts.config_dir(env))
    ca, cert, key = (os.path.join(where, name) for name in contexts.TLS_FILES)
    if not os.path.isfile(ca) and not contexts.is_context_tls(where, env):
        # The CLI and compose stop at the missing file, checking or not (docker/cli's
        # ClientOptions keep ca.pem's path; a context's TLS has no such default).
        variable = "DOCKER_TLS_VERIFY" if verify else "DOCKER_TLS"
        raise ConfigError(
            f"{variable} turns TLS on, and {where} has no ca.pem: the docker CLI and compose refuse to "
            f"reach the engine so (`docker version`: open {ca}: no such file or directory)",
            "Put the engine's CA certificate there as ca.pem (with cert.pem and key.pem where the engine "
            "checks clients), or set DOCKER_CERT_PATH to the directory that holds them. A Docker context "
            "given a certificate and no CA (`docker context create NAME --docker host=...,cert=...,key=...`) "
            "checks the engine against the system's CAs.",
        )
    pair = (cert, key) if os.path.isfile(cert) and os.path.isfile(key) else None
    if not verify:
        _unchecked_engine_is_chosen()
        return docker.TLSConfig(client_cert=pair, verify=False)
    return docker.TLSConfig(client_cert=pair, ca_cert=ca if os.path.isfile(ca) else _system_cas(env), verify=True)


def _unchecked_engine_is_chosen() -> None:
    """Keep urllib3 from warning that the engine's certificate is not checked: the user chose
    that (DOCKER_TLS, a context's skip-tls-verify), and the docker CLI goes on without a word.
    urllib3 printed its InsecureRequestWarning, two lines, at each of a command's requests (six
    for a `prune --dry-run`), through a build's output."""
    from urllib3.exceptions import InsecureRequestWarning

    warnings.filterwarnings("ignore", category=InsecureRequestWarning)


def _system_cas(env: Mapping[str, str]) -> str | None:
    """The system's CA file, as the docker CLI finds it for a context holding no CA (a client
    certificate alone): SSL_CERT_FILE, else OpenSSL's own file (Debian's ca-certificates). The SDK
    would check against requests' bundle (certifi), which lacks a CA the machine's admin added."""
    import ssl

    for candidate in (env.get("SSL_CERT_FILE"), ssl.get_default_verify_paths().openssl_cafile):
        if candidate and os.path.isfile(candidate):
            return candidate
    return None


def _keep_engine_ca(api: Any) -> None:
    """Have the SDK's API client check the engine's TLS certificate as DOCKER_TLS_VERIFY and
    DOCKER_CERT_PATH say: against their CA, or not at all. requests lets REQUESTS_CA_BUNDLE or
    CURL_CA_BUNDLE (set where a proxy re-signs HTTPS) replace a session's own CA at each request:
    no TLS engine (a GitLab docker:dind service) answered espdock then, while the docker CLI,
    which reads neither, did."""
    merge = api.merge_environment_settings

    def merged(url: str, proxies: Any, stream: Any, verify: Any, cert: Any) -> Any:
        if (verify is None or verify is True) and api.verify is not True:
            verify = api.verify  # the engine's CA file, or False: not the system's CAs
        return merge(url, proxies, stream, verify, cert)

    api.merge_environment_settings = merged


def _reuse_ssh_connections(api: Any) -> None:
    """Keep API's connections to an ssh:// engine open from one request to the next, as the
    docker CLI does. The SDK's shell-out adapter makes a new connection pool at every request,
    so each request ran `ssh HOST docker system dial-stdio` anew: a login (0.35 s here, and a
    passphrase or a key touch wherever the user's key asks for one) and a docker CLI started on
    the remote host. A no-change build made 9 of them, a first build 45. Its sockets could not
    be kept either: each answer closes the ssh process's output, which it hands out as the file
    to read answers from."""
    sshconn = importlib.import_module("docker.transport.sshconn")

    class Socket(sshconn.SSHSocket):
        def makefile(self, mode: str) -> Any:
            if not self.proc:
                self.connect()
            # Each answer gets, and closes, its own file on the ssh process's output; the
            # reading stops at the answer's end, so nothing of the next is read into it.
            reader = os.fdopen(os.dup(self.proc.stdout.fileno()), "rb")
            # Where the SDK looks for an attached stream's socket; espdock attaches through the
            # docker CLI, so no stream is read past this file's buffer.
            reader.channel = self
            return reader

        def usable(self) -> bool:
            """The ssh process runs and has sent nothing unasked (an engine closing the stream)."""
            if self.proc is None or self.proc.poll() is not None:
                return False
            readable, _, _ = select.select([self.proc.stdout], [], [], 0)
            return not readable

    class Connection(sshconn.SSHConnection):
        def connect(self) -> None:
            sock = Socket(self.ssh_host)
            sock.settimeout(self.timeout)
            sock.connect()
            self.sock = sock

    class Pool(sshconn.SSHConnectionPool):
        def _new_conn(self) -> Any:
            return Connection(None, self.timeout, self.ssh_host)

        def _get_conn(self, timeout: float | None = None) -> Any:
            conn = super()._get_conn(timeout)
            if conn.sock is not None and not conn.sock.usable():
                with suppress(OSError):  # the ssh process may be gone: its input is then a broken pipe
                    conn.close()  # the request connects anew
            return conn

    adapter = api.get_adapter(api.base_url)
    pool = Pool(timeout=adapter.timeout, maxsize=adapter.max_pool_size, host=adapter.ssh_host)
    adapter.get_connection = lambda url, proxies=None: pool
    close = adapter.close

    def closed() -> None:
        pool.close()
        close()

    adapter.close = closed
