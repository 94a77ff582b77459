"""The hashed locks of the workspace's Python dependency sets, and whether each is up to date.

Each lock is compiled from one source by uv (`uv pip compile --generate-hashes`), for the Python
that installs it, and installed with `pip install --require-hashes`. Its header records the
sha256 of every input it was made from (its source and the locks it is constrained by), so
whether it is stale is decided offline, without uv. For pyproject.toml the digest covers only
what decides the lock: [project]'s requires-python, dependencies and optional-dependencies.

docker/idf/requirements.txt is not locked: it is installed into ESP-IDF's own venv on top of
what IDF installed under its constraints, which only the real IDF image knows (docs/reproducibility.md, Locks).
"""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import tomllib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path

from espdock import downloads, scratch
from espdock.build.steps import EnsureImage, Plan
from espdock.config import Config, resolve_ca_bundle
from espdock.defaults import locate
from espdock.errors import LockError
from espdock.layout import ROSDEP_LOCK
from espdock.ros import rosdeps, testdeps
from espdock.ros.plan import base_image, ros_image
from espdock.ros.rosdeps import ROS_IMAGE_PYTHON
from espdock.ros.system_python import SystemPython, probe_image
from espdock.workspace import BuildInputs, LeftOut, Package, select_up_to, text_digest, write_atomically

INPUT_MARK = "# espdock-lock-input:"
FIX = "run `espdock lock`"


@dataclass(frozen=True)
class LockSpec:
    """LOCK compiled from SOURCE with uv ARGS, consistent with the CONSTRAINTS locks (paths
    relative to the workspace root). PROJECT: only where pyproject.toml's project has that name."""

    lock: str
    source: str
    args: tuple[str, ...]
    constraints: tuple[str, ...] = ()
    project: str | None = None

    @property
    def inputs(self) -> tuple[str, ...]:
        return (self.source, *self.constraints)

    def command(self, paths: Mapping[str, str] | None = None) -> list[str]:
        """The uv arguments after `uv pip compile`, with the inputs at PATHS (default: their names)."""
        where = paths or {}
        constraints = [arg for c in self.constraints for arg in ("-c", where.get(c, c))]
        return ["--generate-hashes", *self.args, where.get(self.source, self.source), *constraints]


# Every lock, in the order they are made (a lock after the locks it is constrained by).
LOCKS = (
    LockSpec("docker/ros-runtime.txt", "docker/ros-runtime.in", ROS_IMAGE_PYTHON),
    # Installed on top of the runtime venv in the build stage: what both need stays at the runtime's pins.
    LockSpec("docker/ros-build.txt", "docker/ros-build.in", ROS_IMAGE_PYTHON, ("docker/ros-runtime.txt",)),
    # espdock's own development and test environment (make test), for any Python it supports.
    LockSpec(
        "requirements/dev.txt",
        "pyproject.toml",
        ("--universal", "--python-version", "3.11", "--extra", "test"),
        project="espdock",
    ),
)


def digest(rel: str, data: bytes) -> str:
    """The sha256 a lock records for its input REL holding DATA: of what it says, so a clone with
    other line endings finds the same lock current (espdock.workspace.text_digest)."""
    if Path(rel).name == "pyproject.toml":
        project = tomllib.loads(data.decode("utf-8-sig")).get("project", {})
        wanted = {k: project.get(k) for k in ("requires-python", "dependencies", "optional-dependencies")}
        data = json.dumps(wanted, sort_keys=True).encode()
    return text_digest(data)


def header(spec: LockSpec, digests: Mapping[str, str]) -> str:
    """The comment a lock starts with: where it comes from, how it was made, what from."""
    lines = [
        f"# Made by `espdock lock` from {spec.source}: edit that, then {FIX}.",
        f"# Install with `pip install --require-hashes -r {spec.lock}`. Compiled with:",
        f"#   uv pip compile {shlex.join(spec.command())}",
        *(f"{INPUT_MARK} {rel} sha256={digests[rel]}" for rel in spec.inputs),
    ]
    return "\n".join(lines) + "\n"


def recorded_inputs(lock_text: str) -> dict[str, str]:
    """The input digests a lock's header records, by path."""
    found = {}
    for line in lock_text.splitlines():
        if line.startswith(INPUT_MARK):
            rel, _, sha = line.removeprefix(INPUT_MARK).strip().partition(" sha256=")
            found[rel] = sha
    return found


def stale_reason(spec: LockSpec, lock_text: str | None, digests: Mapping[str, str]) -> str | None:
    """Why the lock (LOCK_TEXT, None when missing) does not match its inputs' DIGESTS; None when it does."""
    if lock_text is None:
        return f"{spec.lock} is missing"
    recorded = recorded_inputs(lock_text)
    if not recorded:
        return f"{spec.lock} was not made by `espdock lock` (its header records no source)"
    for rel in spec.inputs:
        if recorded.get(rel) != digests[rel]:
            return f"{spec.lock} is stale: {rel} changed since it was locked"
    if header(spec, digests) not in lock_text:
        return f"{spec.lock} is stale: it was compiled with other uv arguments"
    return None


def applies(spec: LockSpec, root: Path) -> bool:
    """Whether the workspace at ROOT has SPEC's lock (its own, or espdock's packaged default)."""
    if spec.project is None:
        return locate(root, spec.source) is not None
    pyproject = root / "pyproject.toml"
    try:
        return tomllib.loads(pyproject.read_text()).get("project", {}).get("name") == spec.project
    except (OSError, tomllib.TOMLDecodeError):
        return False


def _state(spec: LockSpec, root: Path) -> tuple[str | None, dict[str, str]]:
    """The lock's text (None when missing) and its inputs' current digests."""
    digests = {}
    for rel in spec.inputs:
        path = locate(root, rel)
        if path is None:
            raise LockError(f"{rel} is missing, so {spec.lock} cannot be checked or made", f"Restore {rel}.")
        digests[rel] = digest(rel, path.read_bytes())
    lock = locate(root, spec.lock)
    return (lock.read_text() if lock else None), digests


def plan_locks(plan: Plan) -> tuple[LockSpec, ...]:
    """The locks the images of PLAN are built from."""
    names = {name for step in plan.steps if isinstance(step, EnsureImage) for name, _ in step.spec.inputs}
    return tuple(spec for spec in LOCKS if spec.lock in names)


def stale_locks(root: Path, specs: Iterable[LockSpec]) -> list[str]:
    """Why each lock of SPECS that is missing or stale in the workspace at ROOT is."""
    return [reason for spec in specs if (reason := _unowned(spec, root) or stale_reason(spec, *_state(spec, root)))]


def _unowned(spec: LockSpec, root: Path) -> str | None:
    """Why the workspace at ROOT, with SPEC's source (or a lock it is constrained by) of its own
    but not the lock, has no lock of it: espdock's default stands in, compiled from espdock's
    source. Compared with the workspace's, it was said to be stale, naming a file not there."""
    own = [rel for rel in spec.inputs if (root / rel).is_file()]
    if not own or (root / spec.lock).is_file() or locate(root, spec.lock) is None:
        return None
    return (
        f"{spec.lock} is missing: the workspace has its own {', '.join(own)}, "
        f"and espdock's default {spec.lock} (compiled from espdock's) stands in"
    )


def check_locks(root: Path, specs: Iterable[LockSpec]) -> None:
    """Raise LockError naming every lock of SPECS that is missing or stale in the workspace at ROOT."""
    if problems := stale_locks(root, specs):
        raise LockError(
            "; ".join(problems),
            f"In {root}: {FIX} and commit the locks it writes (or build with --no-locked).",
        )


@dataclass(frozen=True)
class LockResult:
    spec: LockSpec
    # created, updated, unchanged, or default (espdock's packaged lock: none of its files is the workspace's).
    status: str


def uv_binary() -> str:
    """The uv executable of the uv package, a dependency of espdock."""
    try:
        from uv import find_uv_bin

        return find_uv_bin()
    except (ImportError, FileNotFoundError) as exc:
        raise LockError(f"uv is not available: {exc}", "Install espdock with its dependencies (uv is one).") from exc


def lock_workspace(
    root: Path,
    uv: str,
    upgrade: bool = False,
    owner: tuple[int, int] | None = None,
    ca_bundle: Path | None = None,
) -> list[LockResult]:
    """Compile every lock of the workspace at ROOT from its source with the uv binary UV, writing
    the ones that changed; OWNER (uid, gid) gets the files it creates (CA_BUNDLE: downloads.uv_env)."""
    results = []
    for spec in LOCKS:
        if not applies(spec, root):
            continue
        if not any((root / rel).is_file() for rel in (*spec.inputs, spec.lock)):
            results.append(LockResult(spec, "default"))
            continue
        old, digests = _state(spec, root)
        text = header(spec, digests) + _compile(spec, root, uv, old, upgrade, ca_bundle)
        target = root / spec.lock
        before = target.read_text() if target.is_file() else None
        if text == before:
            results.append(LockResult(spec, "unchanged"))
            continue
        if before is None:
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(text)
            if owner is not None:
                os.chown(target, *owner)
        else:
            write_atomically(target, text)
        results.append(LockResult(spec, "created" if before is None else "updated"))
    return results


def _compile(
    spec: LockSpec, root: Path, uv: str, previous: str | None, upgrade: bool, ca_bundle: Path | None = None
) -> str:
    """uv's lock of SPEC, keeping PREVIOUS's pins where the source allows (unless UPGRADE)."""
    # Inputs of the workspace's own by their relative paths (so uv's "# via" notes name them so),
    # espdock's defaults by their absolute ones, named in the lock by their relative ones too:
    # the lock is committed, and the same for everyone wherever espdock is installed.
    paths = {rel: rel if (root / rel).is_file() else str(locate(root, rel)) for rel in spec.inputs}
    renamed = {path: rel for rel, path in paths.items() if path != rel}
    with scratch.scratch_dir("espdock-lock-") as tmp:
        output = tmp / "lock.txt"
        output.write_text(previous or "")
        argv = [uv, "pip", "compile", "--quiet", "--no-header", *spec.command(paths), "-o", str(output)]
        argv += ["--upgrade"] if upgrade else []
        env = downloads.uv_env(tmp, ca_bundle)
        result = subprocess.run(argv, cwd=root, env=env, capture_output=True, text=True, check=False)
        if result.returncode != 0:
            raise LockError(
                f"uv could not lock {spec.lock} from {spec.source}:\n{result.stderr.strip()}",
                downloads.network_hint(result.stderr, env, "uv", FIX)
                or f"Fix {spec.source} (or the network), then {FIX} again.",
            )
        text = output.read_text()
    for path, rel in renamed.items():
        text = text.replace(path, rel)
    return text


def _rosdep_state(
    config: Config, packages: tuple[Package, ...], inputs: BuildInputs
) -> tuple[rosdeps.RosImage, dict[str, tuple[str, ...]], str | None]:
    """The chosen image, the keys it lacks per package, and why the rosdep lock is stale (None: current)."""
    _, _, image = ros_image(config, inputs)
    needed = rosdeps.needed_keys(packages, image)
    lock = rosdeps.read_lock(inputs.rosdep_lock, ROSDEP_LOCK)
    present = [p.name for p in packages]
    return image, needed, rosdeps.stale_reason(lock, needed, image, ROSDEP_LOCK, present)


def stale_rosdep_lock(root: Path, reason: str) -> LockError:
    """What a build under --locked says of a stale rosdep lock (REASON: why it is)."""
    return LockError(reason, f"In {root}: {FIX} and commit {ROSDEP_LOCK} (or build with --no-locked).")


# Said before the lock is made: uv against an index that does not answer retries for minutes.
RESOLVING = f"{ROSDEP_LOCK}: resolving the workspace's dependencies (rosdep; uv against the package index for pip's)"


def rosdep_lock_stale(config: Config, packages: tuple[Package, ...], inputs: BuildInputs) -> str | None:
    """Why the workspace's rosdep lock does not answer for PACKAGES; None when it does."""
    return _rosdep_state(config, packages, inputs)[2]


def lock_rosdeps(
    root: Path,
    config: Config,
    packages: tuple[Package, ...],
    inputs: BuildInputs,
    env: Mapping[str, str],
    owner: tuple[int, int] | None = None,
    refresh: bool = True,
    unresolved_ok: bool = True,
    notify: Callable[[str], None] = lambda text: None,
) -> tuple[str, str, bytes | None]:
    """Write ROOT/rosdep.lock.json: rosdep's resolution of the packages' dependencies for the
    chosen ROS image (REFRESH: `rosdep update` first). Returns its status (created, updated,
    unchanged, not needed), where rosdep's database came from, with its age, and the lock's
    content. Not UNRESOLVED_OK (a build's refresh): it is not written where it leaves any key
    unresolved (a COLCON_IGNORE put in for a moment, a key misspelt): the committed file named
    the key as served by nothing, changed by a build that was refused, or one of a selection
    beside the package needing it; `espdock lock` writes it all the same."""
    image, needed, _ = _rosdep_state(config, packages, inputs)
    tests = testdeps.keys_for_tests(packages, image)
    target = root / ROSDEP_LOCK
    if not needed and not tests and not target.is_file():
        return "not needed (the image provides every dependency)", "", None
    notify(RESOLVING)
    ca = resolve_ca_bundle(config, env)
    if (needed or tests) and refresh:
        rosdeps.update_database(env, image.distro, root, ca)
    from espdock.images.keyed import age_text

    system = official_python(config, inputs, env) if image.flavour == "official" else None
    lock = rosdeps.resolve_workspace(packages, image, root, env, uv_binary(), system, ca)
    if tests:  # apart from the build's: only `espdock test` installs them
        lock[testdeps.SECTION] = testdeps.resolve(packages, image, root, env, uv_binary(), system, ca)
    if needed or tests:
        lock["sources"] = rosdeps.database_sources(env, root)
    text = rosdeps.lock_text(lock)
    age = rosdeps.database_age(env, root)
    database = f"rosdep database in {rosdeps.cache_dir(env, root)}" + (
        f", updated {age_text(age)} ago" if age is not None else ""
    )
    before = target.read_text() if target.is_file() else None
    if text == before or (before is not None and _same_but_sources(before, lock)):
        # Only where rosdep's database came from differs (a private rule's file:// path on
        # another machine): the resolution is the same, and the committed file churned between
        # teammates, leaking their home directories into git.
        return "unchanged", database, before.encode()
    keys = lock.get("keys", {})  # as rosdeps.check_dependencies reads it
    unserved = sorted({k for ks in needed.values() for k in ks if not keys.get(k, {}).get("installer")})
    test_keys = lock.get(testdeps.SECTION, {}).get("keys", {})  # as testdeps.check_tests reads them
    unserved += sorted(
        {k for ks in tests.values() for k in ks if not test_keys.get(k, {}).get("installer")} - {*unserved}
    )
    # Keys the lock on disk already leaves unresolved (`espdock lock` wrote them so): each later
    # dependency edit went unlocked, and `espdock run` then refused the stale lock.
    already = _unserved_in(before)
    unserved = [key for key in unserved if key not in already]
    if unserved and not unresolved_ok:
        # A CI build (--locked) refuses the missing or stale lock: say now what writes it.
        return (
            f"not written (it would leave {', '.join(unserved)} unresolved; `espdock lock` writes it so, "
            "for a build under --locked, as CI's)",
            database,
            text.encode(),
        )
    if before is None:
        target.write_text(text)
        if owner is not None:
            os.chown(target, *owner)
        return "created", database, text.encode()
    write_atomically(target, text)
    return "updated", database, text.encode()


def _unserved_in(text: str | None) -> set[str]:
    """The keys TEXT (a rosdep.lock.json) names as served by nothing, the build's and the tests'."""
    try:
        recorded = json.loads(text) if text is not None else {}
    except ValueError:
        return set()
    sections = [recorded, recorded.get(testdeps.SECTION)] if isinstance(recorded, dict) else []
    return {
        key
        for section in sections
        if isinstance(section, dict) and isinstance(section.get("keys"), dict)
        for key, entry in section["keys"].items()
        if isinstance(entry, dict) and not entry.get("installer")
    }


def _same_but_sources(text: str, lock: dict) -> bool:
    """Whether TEXT (a rosdep.lock.json) says what LOCK says, but for where its database came from."""
    try:
        recorded = json.loads(text)
    except ValueError:
        return False
    return isinstance(recorded, dict) and {k: v for k, v in recorded.items() if k != "sources"} == {
        k: v for k, v in lock.items() if k != "sources"
    }


def official_python(config: Config, inputs: BuildInputs, env: Mapping[str, str]) -> Callable[[], SystemPython]:
    """How to read the official ROS image's system Python (a container of the image, pulled
    if needed): called only when the lock has pip packages to resolve beside apt's."""
    ref = base_image(config, inputs.ros_official_dockerfile)

    def run(argv: tuple[str, ...]) -> tuple[int, list[str]]:
        from espdock.images import bootstrap
        from espdock.images.specs import RunSpec

        engine = bootstrap.ensure_engine(env, lambda text: None)
        bootstrap.ensure_base_image(engine, ref, config, lambda text: None)
        lines: list[str] = []
        return engine.run(RunSpec(image=ref, argv=argv, workdir="/", env=(("HOME", "/tmp"),)), lines.append), lines

    return lambda: probe_image(ref, run)


def current_test_inputs(
    root: Path,
    config: Config,
    packages: tuple[Package, ...],
    inputs: BuildInputs,
    locked: bool,
    env: Mapping[str, str],
    owner: tuple[int, int] | None = None,
    tested: tuple[Package, ...] | None = None,
    notify: Callable[[str], None] = lambda text: None,
) -> tuple[BuildInputs, str | None]:
    """current_rosdep_inputs for `espdock test`: a lock whose test part answers too. Without
    rosdep's sources, the lock as it is where it answers for the packages TESTED (default: all)
    and what they need, as a build does (testdeps.check_tests then names a test key it lacks)."""
    image, _, reason = _rosdep_state(config, packages, inputs)
    lock = rosdeps.read_lock(inputs.rosdep_lock, ROSDEP_LOCK)
    reason = reason or testdeps.stale_reason(lock, packages, image, ROSDEP_LOCK)
    if reason is None:
        return inputs, None
    if locked:
        raise LockError(reason, f"In {root}: {FIX} and commit {ROSDEP_LOCK} (or test with --no-locked).")
    # Not written where it leaves a key unresolved, as a build's: testdeps.check_tests names it.
    try:
        status, database, data = lock_rosdeps(
            root, config, packages, inputs, env, owner, refresh=False, unresolved_ok=False, notify=notify
        )
    except rosdeps.DatabaseUnreachable as exc:
        # What the run builds: the packages tested and what they depend on; and the tests' keys.
        tested = packages if tested is None else tested
        built = select_up_to(packages, [p.name for p in tested])
        answered = (testdeps.lock_test_part(lock) or {}).get("keys", {})
        wanted = testdeps.keys_for_tests(tested, image, (p.name for p in packages))
        tests = {
            p.name: [k for k in wanted.get(p.name, ()) if not answered.get(k, {}).get("installer")] for p in tested
        }
        return inputs, offline_note(config, packages, inputs, built, reason, exc, command="test", tests=tests)
    return replace(inputs, rosdep_lock=data), f"{ROSDEP_LOCK} {status} ({reason}; {database})"


def current_rosdep_inputs(
    root: Path,
    config: Config,
    packages: tuple[Package, ...],
    inputs: BuildInputs,
    locked: bool,
    env: Mapping[str, str],
    owner: tuple[int, int] | None = None,
    built: tuple[Package, ...] | None = None,
    ignored: Callable[[], Mapping[str, LeftOut]] | None = None,
    notify: Callable[[str], None] = lambda text: None,
) -> tuple[BuildInputs, str | None]:
    """INPUTS with a rosdep lock that answers for the packages: the current one; else, unless
    LOCKED (which refuses a stale one), one made now. Where rosdep's database cannot be fetched,
    the lock as it is, when it answers for the packages BUILT (default: all). The second value
    says what was done (or, the lock current for the build, that its test part is not).
    IGNORED: as for rosdeps.check_dependencies."""
    image, _, reason = _rosdep_state(config, packages, inputs)
    if reason is None:
        lock = rosdeps.read_lock(inputs.rosdep_lock, ROSDEP_LOCK)
        if lock is not None and (tests := testdeps.stale_reason(lock, packages, image, ROSDEP_LOCK)):
            # A build needs only the build part, and a rename left the test part naming the old
            # package: the lock committed after the build then stopped CI's `espdock test --locked`.
            return inputs, f"note: {tests}; `espdock lock` (or `espdock test`) refreshes it before you commit it"
        return inputs, None
    if locked:
        raise stale_rosdep_lock(root, reason)
    built = packages if built is None else built
    try:
        status, database, data = lock_rosdeps(
            root, config, packages, inputs, env, owner, refresh=False, unresolved_ok=False, notify=notify
        )
    except rosdeps.DatabaseUnreachable as exc:
        return inputs, offline_note(config, packages, inputs, built, reason, exc, ignored)
    return replace(inputs, rosdep_lock=data), f"{ROSDEP_LOCK} {status} ({reason}; {database})"


def offline_note(
    config: Config,
    packages: tuple[Package, ...],
    inputs: BuildInputs,
    built: tuple[Package, ...],
    reason: str,
    unreachable: rosdeps.DatabaseUnreachable,
    ignored: Callable[[], Mapping[str, LeftOut]] | None = None,
    command: str = "build",
    tests: Mapping[str, list[str]] | None = None,
) -> str:
    """What a build does without rosdep's database: it goes on with the lock as it is when that
    answers for every key of the packages BUILT the image lacks (else LockError naming the
    packages that need the database, and those that could build; or, where every such key is a
    workspace package an ignore marker leaves out (IGNORED), rosdeps.check_dependencies' error
    naming the markers: no database would answer for them). TESTS: each package `espdock test`
    tests, with its test keys the lock does not answer (they need the database as much)."""
    image, needed, _ = _rosdep_state(config, packages, inputs)
    answered = (rosdeps.read_lock(inputs.rosdep_lock, ROSDEP_LOCK) or {}).get("keys", {})

    def unanswered(package: Package) -> list[str]:
        return [k for k in needed.get(package.name, ()) if not answered.get(k, {}).get("installer")]

    blocked = {p.name: keys for p in built if (keys := unanswered(p))}
    for name, keys in (tests or {}).items():
        if keys:  # said as well, not the build's "need nothing more from rosdep" and then the tests' refusal
            blocked[name] = list(dict.fromkeys([*blocked.get(name, []), *keys]))
    marked = ignored() if ignored and blocked else {}
    if blocked and all(key in marked for keys in blocked.values() for key in keys):
        checked = [p for p in built if p.name in blocked]
        rosdeps.check_dependencies(checked, needed, None, image, ignored=lambda: marked)
    if not blocked:
        return (
            f"{reason}, and {unreachable.message}; the packages built need nothing more from rosdep, "
            f"so they build without it ({ROSDEP_LOCK} is left as it is)"
        )
    # Those that need nothing from rosdep, nor does any workspace package they depend on (of those
    # tested, where TESTS says which).
    others = [
        p.name
        for p in built
        if p.name not in blocked
        and (tests is None or p.name in tests)
        and not any(unanswered(d) for d in select_up_to(packages, [p.name]))
    ]
    shown = {k: f"{k} ({marked[k].what})" for k in marked}
    lines = "\n".join(f"  {name}: {', '.join(shown.get(k, k) for k in keys)}" for name, keys in blocked.items())
    if isinstance(unreachable, rosdeps.DatabaseUnwritable):
        hint = f"{unreachable.hint} Then {FIX}."
    else:
        hint = (
            "Reach rosdep's sources (or a local copy: ROSDEP_SOURCE_PATH for its rules, ROSDISTRO_INDEX_URL "
            f"for the rosdistro index, as rosdep reads both), then {FIX}."
        )
    if others:
        hint += f" Meanwhile the others {command}: `espdock {command} {' '.join(others)}`."
    refused = LockError(
        f"{reason}, and {unreachable.message}; {len(blocked)} package(s) built need rosdep for keys the "
        f"{image.flavour} ROS image lacks and {ROSDEP_LOCK} does not answer:\n{lines}",
        hint,
    )
    refused.keys = tuple(sorted({key for keys in blocked.values() for key in keys}))
    raise refused
