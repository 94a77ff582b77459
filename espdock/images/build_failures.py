"""What a failed image build's output says to do: a step that could not reach the network (and
the proxy it went through), a base image that could not be pulled, a script with Windows line
endings. Read from the build's lines as they stream (NetworkWatch) and its last lines."""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from urllib.parse import urlsplit

# A build step's words for a network it could not reach: apt's ("Temporary failure resolving
# 'deb.debian.org'", a proxy's "Could not connect to ... Connection refused"), pip's and uv's.
NETWORK_FAILURE = re.compile(
    r"Temporary failure (resolving|in name resolution)|Could not resolve (host|')|Name or service not known"
    r"|Network is unreachable|No route to host|Failed to establish a new connection"
    r"|Could not connect to \S+.*(refused|timed out)|dns error",
    re.IGNORECASE,
)
# What a step that reached the network prints: apt's fetches, pip's and uv's downloads.
DOWNLOADED = re.compile(r"^(Get:\d+ |Downloading |Downloaded |Saved )")
BUILDKIT_LINE = re.compile(r"^#(?P<step>\d+) (?:\d+\.\d+ )?(?P<text>.*)")  # BuildKit's: its step, seconds into it
CLASSIC_STEP = re.compile(r"^(?:STEP|Step) (?P<step>\d+)/\d+ ?:")  # the engine API builder's (Buildah's, Docker's)
READ_THE_OUTPUT = "Read the build output above; run with --verbose for all of it."


class NetworkWatch:
    """Each step's first line saying it could not reach the network, and whether it downloaded
    anything: apt's come as warnings long before its last words ("Unable to locate package
    python3"), out of the tail. Only the failed step counts, and only where it reached nothing:
    one dead source of several, or a retry that then succeeded, is no network out of reach."""

    def __init__(self) -> None:
        self.found: dict[str, str] = {}
        self.fetched: set[str] = set()
        self.failed: list[str] = []
        self.step = ""  # the classic builder's step its lines belong to

    def __call__(self, line: str) -> None:
        if classic := CLASSIC_STEP.match(line):
            self.step = classic.group("step")
            return
        buildkit = BUILDKIT_LINE.match(line)
        step, text = (buildkit.group("step"), buildkit.group("text")) if buildkit else (self.step, line)
        text = text.strip()
        if buildkit and text.startswith("ERROR"):
            self.failed.append(step)
        elif DOWNLOADED.match(text):
            self.fetched.add(step)
        elif NETWORK_FAILURE.search(text):
            self.found.setdefault(step, text)

    @property
    def line(self) -> str | None:
        """What the failed step (BuildKit's `#N ERROR`, else the classic builder's last) said of the network."""
        return next(
            (self.found[s] for s in self.failed or [self.step] if s in self.found and s not in self.fetched), None
        )


# Where an HTTP proxy for image builds is set: Compose's BuildKit builds take the Docker CLI's
# (`proxies`, made build args), the engine API's builder (Buildah under Podman) the engine's own.
CLI_PROXIES = "name it in the Docker CLI's config (`proxies` in ~/.docker/config.json), which image builds take"
ENGINE_PROXIES = (
    "set HTTP_PROXY and HTTPS_PROXY in the environment of the engine's service, which Podman passes "
    "into its builds (http_proxy in containers.conf, on by default)"
)


def network_hint(line: str | None, proxies: str = CLI_PROXIES) -> str | None:
    if line is None:
        return None
    # Around what matched: pip's words come after a long repr of its connection object.
    start = max(0, (match.start() - 60) if (match := NETWORK_FAILURE.search(line)) else 0)
    shown = ("... " if start else "") + line[start : start + 200] + (" ..." if len(line) > start + 200 else "")
    return (
        f"A step of the build could not reach the network ({shown}): its downloads (apt, pip, git) need "
        f"it. Behind an HTTP proxy, {proxies}; without a network, build the images where one answers and "
        "bring them here (`docker save`, `docker load`), or pull them from a cache registry (cache_registry)."
    )


def buildkit_hint(tail: Sequence[str], offline: str | None = None, proxies: Mapping[str, str] | None = None) -> str:
    """What to do about a failed BuildKit build, from the last lines it printed (OFFLINE: a line of
    its output that said the network was out of reach; PROXIES: those the CLI's config gives builds)."""
    output = "\n".join(tail)
    for load in re.finditer(r"^#(\d+) \[(?:\S+ )?internal\] load metadata for (\S+)", output, re.MULTILINE):
        # That step's own error, or the solver's word on it: not any step's error after a base
        # image that was there (a RUN that failed read as "not here and could not be pulled").
        step, ref = load.groups()
        if re.search(rf"^#{step} ERROR", output, re.MULTILINE) or f"resolve source metadata for {ref}" in output:
            return (
                f"{ref} is not here and could not be pulled: is a registry reachable? "
                "Or load the image locally (docker load) or point espdock.toml at one you have."
            )
    if config := re.search(r"mkdir (\S*\.docker): (permission denied|read-only file system)", output, re.I):
        # Compose's build writes the docker CLI's config dir first (buildx state); a HOME
        # espdock can read but not write (or one on a read-only mount) fails every image build so.
        return (
            f"The docker CLI could not make its config dir {config.group(1)}: point DOCKER_CONFIG at a "
            "directory you can write (or make that one writable)."
        )
    return line_endings_hint(output) or proxy_hint(offline, proxies or {}) or network_hint(offline) or READ_THE_OUTPUT


def proxy_hint(line: str | None, proxies: Mapping[str, str]) -> str | None:
    """Where the network failure LINE names the proxy the CLI's config gives builds: the hint to
    name a proxy there sent the user to set what they had set."""
    for variable in ("HTTP_PROXY", "HTTPS_PROXY", "ALL_PROXY"):
        parts = urlsplit(proxies.get(variable, ""))
        try:
            port = parts.port
        except ValueError:
            port = None
        # apt names it with its port ("Could not connect to H:P"), or alone ("Could not resolve 'H'").
        if line and parts.hostname and re.search(rf"(?<![\w.-]){re.escape(parts.hostname)}(?![\w.-])", line):
            where = f"{parts.hostname}:{port}" if port else parts.hostname
            return (
                f"The proxy the Docker CLI's config names ({variable} {where}, `proxies` in its config.json) "
                "did not let a step of the build through: check that it is up, and its address and "
                "credentials there."
            )
    return None


# What a shell says of a script with Windows line endings: dash's `set -eu\r`, bash's `\r` as a
# command, env's `python3\r` (shown as it is, or in bash's $'...' quoting).
CRLF_SYMPTOM = re.compile(r"Illegal option -\r?$|\$'\\r'|\r['\u2019:]", re.MULTILINE)


def line_endings_hint(output: str) -> str | None:
    """What to do when a build failed on a Dockerfile's script with Windows line endings (a
    checkout with Git for Windows' autocrlf)."""
    if not CRLF_SYMPTOM.search(output):
        return None
    return (
        "A script the build runs has Windows line endings (CRLF), as a checkout with Git for Windows' "
        "core.autocrlf makes them: put `* text=auto eol=lf` in the repository's .gitattributes and check the "
        "files out again (`git rm --cached -r . && git reset --hard`), or convert them (dos2unix)."
    )
