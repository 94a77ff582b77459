"""The workspace's dependencies from package.xml: which the ROS image provides, which rosdep
installs, and the lock that records rosdep's answer (rosdep.lock.json).

Every dependency of a ROS package that is no workspace package is a rosdep key. The image's
own ament index (known from its inputs: the wheels its locks install) provides some; the
rest go to the real rosdep, resolved for the OS the image runs (pinned beside the image as
Dockerfile ARG ROSDEP_OS). Its answer is written to the lock by `espdock lock` (or by a build
whose lock is stale, unless --locked), and the build and runtime images install exactly what
the lock names: apt packages in one layer, pip packages from the lock's hashed lines.

Pure functions (what is needed, whether the lock is current, what is missing) are used by
the plan; resolve_workspace and write_lock talk to rosdep and uv and are used only when the
lock must be made.
"""

from __future__ import annotations

import difflib
import hashlib
import json
import os
import re
import shutil
import subprocess
import time
import warnings
from collections.abc import Callable, Collection, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from espdock import downloads, scratch
from espdock.defaults import locate
from espdock.errors import DependencyError, LockBehind, LockError
from espdock.layout import ROSDEP_LOCK, xdg_dir
from espdock.ros import pypi_names
from espdock.ros.system_python import SystemPython, normalise
from espdock.workspace import LeftOut, Package, PackageKind, root_key, workspace_gone

# The ROS images' Python: Debian bookworm's 3.11 on x86_64 (glibc 2.36), whatever runs uv.
ROS_IMAGE_PYTHON = ("--python-version", "3.11", "--python-platform", "x86_64-manylinux_2_36")

# 2: a rule that installs nothing (an empty list: rosdep's "satisfied") is served, where format 1
# recorded it as unserved, and builds needing it were refused. An older format is stale.
FORMAT = 2
FIX = "run `espdock lock`"
# Where rosdep's database (what `rosdep update` downloads) is cached, under the user's cache dir.
CACHE_SUBDIR = "espdock/rosdep"
# rosdep's own default sources list (rosdistro's rosdep/sources.list.d/20-default.list), used
# when neither ROSDEP_SOURCE_PATH nor /etc/ros/rosdep/sources.list.d gives one.
DEFAULT_SOURCES = """\
yaml https://raw.githubusercontent.com/ros/rosdistro/master/rosdep/osx-homebrew.yaml osx
yaml https://raw.githubusercontent.com/ros/rosdistro/master/rosdep/base.yaml
yaml https://raw.githubusercontent.com/ros/rosdistro/master/rosdep/python.yaml
yaml https://raw.githubusercontent.com/ros/rosdistro/master/rosdep/ruby.yaml
gbpdistro https://raw.githubusercontent.com/ros/rosdistro/master/releases/fuerte.yaml fuerte
"""
# Anchored on the newline, not ^ with MULTILINE: several times faster on a 100 kB lock, which
# every build reads.
_WHEEL = re.compile(r"\n(ros-[a-z0-9-]+)==")
_DEB_NAME = re.compile(r"[a-z0-9][a-z0-9+.-]+")
_NOT_FOUND = re.compile(r"Because (\S+) was not found in the package registry")
# uv's words for a package index it could not reach (no network, a proxy or DNS down).
_INDEX_UNREACHABLE = re.compile(
    r"Failed to fetch|error sending request|dns error|Connection refused|operation timed out|tcp connect error",
    re.IGNORECASE,
)


@dataclass(frozen=True)
class RosImage:
    """What the plan knows of the chosen ROS image before any of it is built."""

    flavour: str  # "wheels" or "official"
    distro: str
    os: str  # what rosdep resolves for, e.g. "debian:bookworm"
    # ROS packages (ament index names) the image has before rosdep adds anything.
    provided: frozenset[str]
    # Locks whose change makes the rosdep lock stale (the wheels' pins constrain its pip part).
    constraints: tuple[tuple[str, str], ...] = ()


def wheel_packages(lock_texts: Iterable[str], distro: str) -> frozenset[str]:
    """The ROS packages a set of wheel locks installs: each `ros-<name>` or `ros-<distro>-<name>`
    wheel puts one package, <name> with underscores, into the ament index."""
    found = set()
    for text in lock_texts:
        for wheel in _WHEEL.findall("\n" + text):
            name = wheel.removeprefix("ros-").removeprefix(f"{distro}-")
            found.add(name.replace("-", "_"))
    return frozenset(found)


def needed_keys(
    packages: Iterable[Package], image: RosImage, workspace: Iterable[str] = ()
) -> dict[str, tuple[str, ...]]:
    """Per ROS package: its dependencies that are neither workspace packages (PACKAGES' and those
    WORKSPACE names besides) nor provided by the image (test-only ones aside: espdock builds, it
    does not run `colcon test`)."""
    packages = tuple(packages)
    names = {p.name for p in packages} | set(workspace)
    needed = {}
    for package in packages:
        if package.kind is not PackageKind.ROS:
            continue
        keys = package.depends - package.test_only_depends - names - image.provided
        if keys:
            needed[package.name] = tuple(sorted(keys))
    return needed


UNKNOWN_KEY = "no rosdep rule: the key is unknown to rosdep's database"
# How like an unknown key a name must be to be offered in its place (difflib's ratio): `std_msg`
# for std_msgs is 0.93, a workspace package's name with one letter swapped about 0.9.
_LIKE = 0.8


def similar_names(key: str, names: Iterable[str]) -> tuple[str, ...]:
    """The NAMES (rosdep's keys, the workspace's packages) that KEY is most likely a typo of, best first."""
    return tuple(difflib.get_close_matches(key, sorted(set(names) - {key}), n=3, cutoff=_LIKE))


def why_text(entry: Mapping) -> str:
    """Why a lock ENTRY's key is served by nothing, with the names it may be a typo of."""
    why = str(entry.get("why") or NOT_LOCKED)
    similar = [str(name) for name in entry.get("similar") or ()]
    return f"{why} (did you mean {' or '.join(similar)}?)" if similar else why


# A key the lock has no entry for: the lock was made before a package.xml named it.
NOT_LOCKED = "not in the lock"


def lock_input(needed: Mapping[str, tuple[str, ...]], image: RosImage) -> str:
    """What a lock answers for: the keys, the image flavour and OS, the constraining locks."""
    data = {
        "keys": {k: list(v) for k, v in sorted(needed.items())},
        "ros_image": image.flavour,
        "os": image.os,
        "distro": image.distro,
        "constraints": dict(image.constraints),
    }
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()


def read_lock(data: bytes | None, name: str) -> dict | None:
    """The lock's content, None when there is none; malformed is an error naming the file."""
    if data is None:
        return None
    try:
        lock = json.loads(data)
        if not isinstance(lock, dict) or not isinstance(lock.get("format"), int):
            raise ValueError(f"not format {FORMAT}")
        if lock["format"] > FORMAT:
            raise LockError(
                f"{name} was made by a newer espdock (its format {lock['format']}, this one's {FORMAT})",
                f"Use that espdock, or delete {name} and {FIX} with this one.",
            )
    except ValueError as exc:
        raise LockError(f"{name} is not an espdock rosdep lock: {exc}", f"Delete it and {FIX}.") from None
    return lock


def stale_reason(
    lock: dict | None,
    needed: Mapping[str, tuple[str, ...]],
    image: RosImage,
    name: str,
    present: Iterable[str] | None = None,
) -> str | None:
    """Why LOCK does not answer for NEEDED on IMAGE; None when it does (or nothing is needed).
    PRESENT: the workspace's packages now, where the caller knows them."""
    if lock is None:
        return f"{name} is missing" if needed else None
    if lock.get("format", FORMAT) != FORMAT:  # a test part has none: its lock's is checked
        return f"{name} was made by an older espdock (format {lock['format']}), which read rosdep's rules otherwise"
    if lock.get("input") != lock_input(needed, image):
        return f"{name} is stale: {_what_changed(lock, needed, image, present)}"
    return None


def _what_changed(
    lock: Mapping, needed: Mapping[str, tuple[str, ...]], image: RosImage, present: Iterable[str] | None = None
) -> str:
    """What the lock answers for that NEEDED on IMAGE does not: the keys each package depends on,
    the image; its locks, where nothing else differs. PRESENT: the workspace's packages now."""
    said = []
    locked = {p: tuple(keys) for p, keys in (lock.get("packages") or {}).items()} if "packages" in lock else None
    present = None if present is None else set(present)
    if locked is not None:
        for package in sorted(set(needed) | set(locked)):
            if present is not None and package not in present:
                # Left out (COLCON_IGNORE), removed or renamed: not a package whose dependencies changed.
                said.append(f"{package} is no package of the workspace now")
                continue
            now, before = set(needed.get(package, ())), set(locked.get(package, ()))
            if now - before:
                said.append(f"{package} now depends on {', '.join(sorted(now - before))}")
            if before - now:
                said.append(f"{package} no longer depends on {', '.join(sorted(before - now))}")
    for field, value in (("ros_image", image.flavour), ("os", image.os), ("ros_distro", image.distro)):
        if field in lock and lock[field] != value:
            said.append(f"{field} is {value}, not {lock[field]}")
    if said:
        return "since it was made, " + "; ".join(said[:6]) + (f" (and {len(said) - 6} more)" if len(said) > 6 else "")
    return "the packages' dependencies, ros_image or its locks changed since it was made"


def unserved(lock: dict | None) -> list[tuple[str, str]]:
    """The keys LOCK (its test part too) records that nothing installs, each with why, in order:
    what a build or test of a package needing one refuses."""
    found: dict[str, str] = {}
    for part in (lock or {}, (lock or {}).get("test") or {}):
        for key, entry in sorted((part.get("keys") or {}).items()):
            if isinstance(entry, dict) and not entry.get("installer") and key not in found:
                found[key] = why_text(entry)
    return list(found.items())


def check_dependencies(
    selected: Iterable[Package],
    needed: Mapping[str, tuple[str, ...]],
    lock: dict | None,
    image: RosImage,
    command: str | None = "build",
    ignored: Callable[[], Mapping[str, LeftOut]] | None = None,
) -> None:
    """Raise DependencyError listing, per selected package, each key neither the image nor the
    lock provides, with the ways out (COMMAND: `espdock build` or `test`, which another selection can
    avoid; None: a command that selects nothing else);
    nothing is built or run then. IGNORED: the workspace packages espdock does not build (an
    ignore marker leaves them out, or they have no package.xml), asked only then: a key that is
    one of them is no rosdep matter."""
    keys = (lock or {}).get("keys", {})
    missing = {p: [k for k in needed.get(p.name, ()) if not keys.get(k, {}).get("installer")] for p in selected}
    if not any(missing.values()):
        return
    markers = {k: m for k, m in (ignored() if ignored else {}).items() if any(k in ks for ks in missing.values())}
    lines = []
    whys = set()
    for package, absent in missing.items():
        if absent:
            whys |= {keys.get(k, {}).get("why", NOT_LOCKED) for k in absent if k not in markers}
            why = "; ".join(
                f"{k}: {markers[k].what}" if k in markers else f"{k}: {why_text(keys.get(k, {}))}" for k in absent
            )
            lines.append(f"  {package.name} ({package.path}): {why}")
    fixes = "; or ".join(sorted({left.fix for left in markers.values()}))
    if not whys:
        raise DependencyError(
            f"{len(lines)} package(s) depend on workspace packages espdock does not build:\n" + "\n".join(lines),
            f"{fixes[0].upper()}{fixes[1:]}; or drop the dependency on it.",
        )
    if whys == {NOT_LOCKED}:
        # Only keys the lock has never seen (a dependency declared, or a typo fixed, since): the
        # lock is behind the package.xml files, not rosdep behind the key.
        again = f"`espdock {command}`" if command else "the command"
        # No lock at all (a fresh clone, a run before any build) is not one behind the manifests.
        state = "is missing" if lock is None else "is older than the package.xml files"
        raise LockBehind(
            f"{ROSDEP_LOCK} {state}:\n" + "\n".join(lines),
            f"Run `espdock lock` (or {again} where rosdep's sources answer: it refreshes the lock) and run again.",
        )
    ways = [
        "add a rosdep rule for the key (a sources.list.d entry; ROSDEP_SOURCE_PATH) and run `espdock lock`",
        "put COLCON_IGNORE in the package's directory",
    ]
    if command is not None:
        ways.append(f"{command} another selection (`espdock {command} PKG...`, or `-- --packages-skip PKG`)")
    if markers:
        ways.insert(0, f"{fixes}, to build the workspace package depended on")
    if any(keys.get(k, {}).get("similar") for absent in missing.values() for k in absent if k not in markers):
        ways.insert(0, "correct the name in the package.xml where it is misspelt")
    # A key rosdep knows nowhere is no more known to the official image.
    if image.flavour == "wheels" and whys - {UNKNOWN_KEY}:
        ways.insert(1, 'use the official ROS image (ros_image = "official" in espdock.toml), whose apt has every '
                       "ROS package of the distro (rclcpp, launch_ros, ...)")  # fmt: skip
    raise DependencyError(
        f"{len(lines)} package(s) depend on what the {image.flavour} ROS image ({image.os}) does not provide "
        "and rosdep cannot install:\n" + "\n".join(lines),
        "Ways out: " + "; or ".join(ways) + ".",
        tuple(sorted({key for absent in missing.values() for key in absent})),
    )


def image_files(lock: dict | None) -> dict[str, bytes]:
    """What the image build installs from LOCK: apt.txt (one package a line) and pip.txt (hashed)."""
    lock = lock or {}
    apt = [str(p) for p in lock.get("apt", [])]
    bad = [p for p in apt if not _DEB_NAME.fullmatch(p)]
    if bad:
        raise LockError(f"rosdep.lock.json names apt packages that are no Debian package names: {bad}", FIX)
    head = "# Staged by espdock from rosdep.lock.json.\n"
    pip = "".join(f"{line}\n" for line in lock.get("pip", []))
    return {"apt.txt": (head + "".join(f"{p}\n" for p in apt)).encode(), "pip.txt": (head + pip).encode()}


# --- making the lock: rosdep and uv ---------------------------------------------------------


class DatabaseUnreachable(LockError):
    """rosdep's database could not be fetched (no network, a source down)."""


class DatabaseUnwritable(DatabaseUnreachable):
    """rosdep's database could not be kept: its cache directory cannot be written. Its hint says
    where, not to reach rosdep's sources."""


def cache_dir(env: Mapping[str, str], root: Path | None = None) -> Path:
    """Where rosdep's database is kept for the workspace at ROOT: one per workspace, so the
    sources one workspace's rosdep was pointed at (a private rule) never serve another."""
    base = xdg_dir(env, "XDG_CACHE_HOME", ".cache") / CACHE_SUBDIR
    if root is None:
        return base
    return base / root_key(Path(root).resolve())


def _unwrapped(said: str) -> str:
    """SAID without urllib's `<urlopen error ...>` wrappers, which rosdep nests one in another."""
    while (inner := re.sub(r"<urlopen error ([^<>]*)>", r"\1", said)) != said:
        said = inner
    return said


def database_age(env: Mapping[str, str], root: Path | None = None) -> float | None:
    """Seconds since rosdep's database was last updated, None when there is none."""
    index = cache_dir(env, root) / "sources.cache" / "index"
    return time.time() - index.stat().st_mtime if index.is_file() else None


def database_sources(env: Mapping[str, str], root: Path | None = None) -> list[str]:
    """What the workspace's rosdep database was made from: each source of its index (type, URL,
    tags) and the rosdistro index it read."""
    from rosdistro import get_index_url

    index = cache_dir(env, root) / "sources.cache" / "index"
    lines = index.read_text().splitlines() if index.is_file() else []
    found = [line.strip() for line in lines if line.strip() and not line.lstrip().startswith("#")]
    return [*found, f"rosdistro index {env.get('ROSDISTRO_INDEX_URL') or get_index_url()}"]


def update_database(
    env: Mapping[str, str], distro: str, root: Path | None = None, ca_bundle: Path | None = None
) -> Path:
    """`rosdep update` into espdock's cache: rosdep's sources (ROSDEP_SOURCE_PATH, else
    /etc/ros/rosdep/sources.list.d, else rosdep's default list) and the rosdistro index's
    distribution (ROSDISTRO_INDEX_URL), as rosdep itself reads them. CA_BUNDLE: as for uv
    (uv_env): rosdep's urllib checks against the system's CAs alone, which behind a TLS-intercepting
    proxy hold not the proxy's."""
    from rosdep2.rosdistrohelper import PreRep137Warning
    from rosdep2.sources_list import get_sources_list_dir, update_sources_list

    cache = cache_dir(env, root)
    sources = Path(get_sources_list_dir())
    try:
        (cache / "sources.cache").mkdir(parents=True, exist_ok=True)
        if not sources.is_dir() or not any(sources.glob("*.list")):
            sources = cache / "sources.list.d"
            sources.mkdir(parents=True, exist_ok=True)
            (sources / "20-default.list").write_text(DEFAULT_SOURCES)
    except OSError as exc:
        # Said as what it is: `rosdep update` failing on it was "reach rosdep's sources".
        raise DatabaseUnwritable(
            f"espdock cannot keep rosdep's database in {cache}: {exc.strerror} ({exc.filename})",
            f"Make {cache_dir(env)} writable, or set XDG_CACHE_HOME to a directory you can write.",
        ) from exc
    failed: list[str] = []
    try:
        with warnings.catch_warnings(), downloads.cert_file(ca_bundle):
            # The default list's gbpdistro source warns on every update, as `rosdep update` itself silences.
            warnings.filterwarnings("ignore", category=PreRep137Warning)
            update_sources_list(
                sources_list_dir=str(sources),
                sources_cache_dir=str(cache / "sources.cache"),
                error_handler=lambda source, exc: failed.append(f"{source.url}: {exc}"),
                ros_distro=distro,
                quiet=True,
            )
    except Exception as exc:  # rosdep raises many kinds (URLError, InvalidData, ValueError)
        raise DatabaseUnreachable(
            f"`rosdep update` failed: {_unwrapped(str(exc))}",
            downloads.network_hint(str(exc), env, "rosdep", FIX)
            or "rosdep's database comes from GitHub (or ROSDEP_SOURCE_PATH / ROSDISTRO_INDEX_URL): reach it, then "
            + FIX
            + ".",
        ) from exc
    if failed:
        raise DatabaseUnreachable(
            "`rosdep update` could not read: " + "; ".join(failed),
            downloads.network_hint(" ".join(failed), env, "rosdep", FIX) or f"Fix the sources, then {FIX}.",
        )
    if root is not None:
        (cache / "root").write_text(str(Path(root).resolve()))
        _remove_gone_databases(cache_dir(env))
    return cache


def _remove_gone_databases(base: Path) -> None:
    """Remove the databases of workspaces since removed (a clone, a CI job's checkout): each
    names its workspace in `root`, and nothing will read it again."""
    for database in base.iterdir():
        try:
            root = (database / "root").read_text()
        except OSError:
            continue  # not a database, or one made before databases named their workspace
        if workspace_gone(root):
            shutil.rmtree(database, ignore_errors=True)


@dataclass(frozen=True)
class Rule:
    installer: str | None  # apt, pip; None: nothing installs it
    packages: tuple[str, ...] = ()
    why: str = ""
    # The PyPI names the key's rules give for other platforms (e.g. osx: pip: [PyYAML]).
    pip_elsewhere: tuple[str, ...] = ()
    # A key rosdep does not know: the names it is most likely a typo of (`std_msg`: std_msgs).
    similar: tuple[str, ...] = ()


def _pip_packages(data: object) -> tuple[str, ...]:
    """Every package a pip rule anywhere in a key's rosdep DATA names, in order (rosdep's
    `pip: {packages: [...]}` and its short form `pip: [...]`)."""
    found: list[str] = []
    if isinstance(data, dict):
        for name, value in data.items():
            if name == "pip" and isinstance(value, dict):
                found += [str(p) for p in value.get("packages") or () if str(p) not in found]
            elif name == "pip" and isinstance(value, list):
                found += [str(p) for p in value if str(p) not in found]
            else:
                found += [p for p in _pip_packages(value) if p not in found]
    return tuple(found)


def rosdep_rules(
    keys: Iterable[str],
    os_spec: str,
    distro: str,
    env: Mapping[str, str],
    root: Path | None = None,
    ca_bundle: Path | None = None,
    names: Iterable[str] = (),
    suggest: Collection[str] = (),
) -> dict[str, Rule]:
    """rosdep's answer for each key on OS_SPEC ("debian:bookworm"), as `rosdep resolve` gives it; a
    key of SUGGEST rosdep does not know, with the rosdep keys and NAMES (the workspace's packages)
    it is most like."""
    from rosdep2 import create_default_installer_context
    from rosdep2.lookup import ResolutionError, RosdepLookup
    from rosdep2.rospkg_loader import DEFAULT_VIEW_KEY
    from rosdep2.sources_list import DataSourceMatcher, SourcesListLoader

    os_name, os_version = os_spec.split(":", 1)
    cache = cache_dir(env, root) / "sources.cache"
    if not (cache / "index").is_file():
        update_database(env, distro, root, ca_bundle)
    matcher = DataSourceMatcher([distro, os_name, os_version])
    loader = SourcesListLoader.create_default(matcher=matcher, sources_cache_dir=str(cache))
    lookup = RosdepLookup.create_from_rospkg(sources_loader=loader)
    view = lookup.get_rosdep_view(DEFAULT_VIEW_KEY)
    context = create_default_installer_context()
    context.set_os_override(os_name, os_version)
    installer_keys = context.get_os_installer_keys(os_name)
    default = context.get_default_os_installer_key(os_name)
    rules = {}
    known: list[str] = []  # rosdep's keys and NAMES, read when a key of SUGGEST is not among them
    for key in sorted(set(keys)):
        try:
            definition = view.lookup(key)
        except KeyError:
            if key in suggest and not known:
                known = [*view.keys(), *names]
            rules[key] = Rule(None, why=UNKNOWN_KEY, similar=similar_names(key, known) if key in suggest else ())
            continue
        try:
            installer, rule = definition.get_rule_for_platform(os_name, os_version, installer_keys, default)
            packages = tuple(str(p) for p in context.get_installer(installer).resolve(rule))
        except (ResolutionError, KeyError):
            rules[key] = Rule(None, why=f"no rosdep rule for {os_spec}")
            continue
        if installer not in ("apt", "pip"):
            rules[key] = Rule(None, why=f"rosdep installs it with {installer}, which the image lacks")
        elif not packages:
            # rosdep's way of saying the key needs nothing on this platform: satisfied as it is.
            rules[key] = Rule(installer)
        else:
            rules[key] = Rule(installer, packages, pip_elsewhere=_pip_packages(definition.data))
    return rules


def for_image(rules: Mapping[str, Rule], image: RosImage, pip_rules: Mapping[str, Rule]) -> dict[str, Rule]:
    """RULES as the image installs them. The wheels venv sees no apt Python package nor any apt
    ROS package: an apt `ros-<distro>-X` rule becomes the wheel of that name, and an apt rule
    naming `python3-*` packages the PyPI project python_rule finds, or a refusal."""
    if image.flavour != "wheels":
        return dict(rules)
    ros_prefix = f"ros-{image.distro}-"
    mapped = {}
    for key, rule in rules.items():
        python = [
            p
            for p in rule.packages
            if (p.startswith("python3-") or p in pypi_names.APT_PYTHON) and p not in pypi_names.APT_KEPT
        ]
        if not rule.packages:
            mapped[key] = rule
        elif rule.installer == "apt" and all(p.startswith(ros_prefix) for p in rule.packages):
            mapped[key] = Rule("pip", rule.packages, f"the wheel(s) {', '.join(rule.packages)}")
        elif rule.installer == "apt" and python:
            mapped[key] = python_rule(key, rule, pip_rules.get(key))
        else:
            mapped[key] = rule
    return mapped


def python_rule(key: str, rule: Rule, sibling: Rule | None) -> Rule:
    """What serves KEY (whose apt RULE installs Python packages) in the wheels venv: the key's
    pip rule for another platform, else its -pip SIBLING key's rule, else the reviewed PyPI
    project (espdock.ros.pypi_names), else nothing, with the reason: never a guessed name."""
    if rule.pip_elsewhere:
        return Rule("pip", rule.pip_elsewhere, "its pip rule for another platform (the venv sees no apt Python)")
    if sibling is not None and sibling.installer == "pip":
        return Rule("pip", sibling.packages, "its -pip rule (the venv does not see apt's Python)")
    project = pypi_names.PYPI_PROJECT.get(key)
    if project is not None and len(rule.packages) == 1:
        return Rule("pip", (project,), f"PyPI's {project} for apt's {rule.packages[0]} (espdock's reviewed table)")
    return Rule(None, why=pypi_names.refusal(key))


def pip_alternatives(keys: Iterable[str]) -> list[str]:
    """The -pip keys rosdistro spells for Python keys (python3-foo: python3-foo-pip, python-foo-pip)."""
    out = []
    for key in keys:
        if key.startswith("python3-"):
            stem = key.removeprefix("python3-")
            out += [f"python3-{stem}-pip", f"python-{stem}-pip"]
    return out


def pip_lock_lines(
    requirements: Iterable[str],
    image: RosImage,
    root: Path,
    uv: str,
    system: SystemPython | None = None,
    ca_bundle: Path | None = None,
) -> tuple[list[str], set[str]]:
    """uv's hashed lock of REQUIREMENTS for the image's Python (one line per package, hashes
    inline), and the requirements PyPI does not have (dropped). SYSTEM: the official image's
    Python, whose installed distributions the lock keeps at their versions."""
    wanted = sorted(set(requirements))
    absent: set[str] = set()
    while wanted:
        with scratch.scratch_dir("espdock-rosdep-") as tmp:
            source = tmp / "rosdep.in"
            source.write_text("".join(f"{r}\n" for r in wanted))
            out = tmp / "rosdep.txt"
            if image.flavour == "wheels":
                args = [*ROS_IMAGE_PYTHON]
                for rel, _ in image.constraints:
                    args += ["-c", str(locate(root, rel))]
            else:  # the official image's system Python (noble: 3.12; the test double: 3.11)
                args = ["--universal", "--python-version", system.version if system else "3.11"]
                if system is not None:
                    installed = tmp / "installed.txt"
                    installed.write_text(system.constraints())
                    args += ["-c", str(installed)]
            argv = [uv, "pip", "compile", "--quiet", "--no-header", "--no-annotate", "--generate-hashes"]
            argv += [*args, str(source), "-o", str(out)]
            result = subprocess.run(
                argv, env=downloads.uv_env(tmp, ca_bundle), check=False, capture_output=True, text=True
            )
            if result.returncode == 0:
                return _one_line_each(out.read_text()), absent
        gone = set(_NOT_FOUND.findall(result.stderr)) & set(wanted)
        if not gone and system is not None:
            raise LockError(
                f"uv could not lock the rosdep pip packages {wanted} beside what the official ROS image's apt "
                f"installed (its Python packages stay at their versions):\n{result.stderr.strip()}",
                "Use a rosdep key whose rule is apt (the image's own Python packages), or another version of the "
                f"package; then {FIX}.",
            )
        if not gone and _INDEX_UNREACHABLE.search(result.stderr):
            # As rosdep's database out of reach: a build goes on with the lock as it is where it
            # answers for the packages built (offline, with the database cached, it stopped them all).
            said = next((line.strip() for line in reversed(result.stderr.splitlines()) if line.strip()), "")
            raise DatabaseUnreachable(
                f"uv could not reach the package index for the rosdep pip packages {wanted} ({said})",
                downloads.network_hint(result.stderr, os.environ, "uv", FIX)
                or f"Reach the package index (PyPI, or the one UV_INDEX_URL names), then {FIX}.",
            )
        if not gone:
            raise LockError(f"uv could not lock the rosdep pip packages {wanted}:\n{result.stderr.strip()}", FIX)
        absent |= gone
        wanted = [r for r in wanted if r not in gone]
    return [], absent


def _one_line_each(text: str) -> list[str]:
    lines, current = [], ""
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        current = f"{current} {line.removesuffix(chr(92)).strip()}".strip()
        if not raw.rstrip().endswith("\\"):
            lines.append(current)
            current = ""
    return lines


def resolve_workspace(
    packages: Iterable[Package],
    image: RosImage,
    root: Path,
    env: Mapping[str, str],
    uv: str,
    system: Callable[[], SystemPython] | None = None,
    ca_bundle: Path | None = None,
) -> dict:
    """The lock for PACKAGES on IMAGE: rosdep's rules for every needed key, as the image installs
    them (CA_BUNDLE: see uv_env)."""
    packages = tuple(packages)
    needed = needed_keys(packages, image)
    keys = sorted({k for ks in needed.values() for k in ks})
    names = [p.name for p in packages]
    wanted = [*keys, *pip_alternatives(keys)]
    rules = rosdep_rules(wanted, image.os, image.distro, env, root, ca_bundle, names, suggest=keys) if keys else {}
    pip_rules = {k: rules[alt] for k in keys for alt in pip_alternatives([k]) if rules.get(alt, Rule(None)).installer}
    mapped = for_image({k: rules[k] for k in keys}, image, pip_rules)
    pip_wanted = [p for rule in mapped.values() if rule.installer == "pip" for p in rule.packages]
    # The official image's Python is read (a container run) only when there is pip to lock.
    installed = system() if pip_wanted and system is not None else None
    pip_lines, absent = pip_lock_lines(pip_wanted, image, root, uv, installed, ca_bundle) if pip_wanted else ([], set())
    entries = {}
    for key, rule in sorted(mapped.items()):
        if rule.installer == "pip" and absent & set(rule.packages):
            entries[key] = {"installer": None, "why": f"PyPI has no {', '.join(sorted(absent & set(rule.packages)))}"}
        elif rule.installer is None:
            entries[key] = {
                "installer": None,
                "why": rule.why,
                **({"similar": list(rule.similar)} if rule.similar else {}),
            }
        else:
            entries[key] = {"installer": rule.installer, "packages": list(rule.packages)}
            if rule.why:
                entries[key]["via"] = rule.why
    return {
        "format": FORMAT,
        "made_by": f"`espdock lock` with rosdep for {image.os}; edit package.xml files, then {FIX}",
        "input": lock_input(needed, image),
        "ros_image": image.flavour,
        "os": image.os,
        "ros_distro": image.distro,
        "packages": {k: list(v) for k, v in sorted(needed.items())},
        "keys": entries,
        "apt": sorted({p for e in entries.values() if e["installer"] == "apt" for p in e["packages"]}),
        "pip": pip_lines,
        **held_by_image(pip_lines, installed),
    }


def held_by_image(pip_lines: Iterable[str], system: SystemPython | None) -> dict:
    """The lock's record of the official image's Python: its version, and the pinned packages
    that stay at what the image installed (pip finds them installed and leaves them)."""
    if system is None:
        return {}
    pins = system.pins()
    held = {}
    for line in pip_lines:
        name, _, rest = line.partition("==")
        version = rest.split()[0] if rest.split() else ""
        if pins.get(normalise(name)) == version:
            held[name] = version
    return {"system_python": {"version": system.version, "kept_as_installed": held}}


def lock_text(lock: Mapping) -> str:
    return json.dumps(lock, indent=1, sort_keys=True) + "\n"
