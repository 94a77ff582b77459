"""`espdock test`: colcon test of the built packages, and what its test tasks wrote.

colcon's test tasks (pytest for ament_python, CTest with ament_cmake_gtest/pytest and the ament
linters for ament_cmake) write xUnit (JUnit) XML files under each package's build dir; `colcon
test-result` counts them by each file's testsuite attributes (colcon-test-result's xunit
parser), plus each CMake package's latest CTest Test.xml (colcon-cmake's ctest parser: one test
per CTest test, which for ament_cmake wraps a gtest executable or a linter). Read here the same
way, so the summary is colcon's count; --results collects the JUnit files only, so they count
colcon's count less the CTest entries.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import posixpath
import pwd
import shutil
import subprocess
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from xml.etree.ElementTree import Element, ElementTree, ParseError

from espdock import durable
from espdock.build.stamps import listing_digest
from espdock.errors import ConfigError, DependencyError, EspdockError, WorkspaceError
from espdock.images.containers import give_to, make_dirs_for, permission_error, prepare_output
from espdock.layout import ROS_BUILD_BASE
from espdock.ros.colcon import NONE_LEFT_OUT, check_colcon_args, full_option, left_out, without_leaving_out
from espdock.workspace import Package

# colcon build's options that colcon test lacks (the build image's colcon, each verb's --help):
# refused before the build with tests, which otherwise ran for minutes and then colcon test
# failed on "unrecognized argument".
BUILD_ONLY = (
    "--ament-cmake-args", "--catkin-cmake-args", "--catkin-skip-building-tests", "--cmake-args", "--cmake-clean-cache",
    "--cmake-clean-first", "--cmake-force-configure", "--cmake-target", "--cmake-target-skip-unavailable",
    "--continue-on-error", "--symlink-install",
)  # fmt: skip
# ROS packages the wheels image cannot give a package's tests: ament's lint packages PyPI lacks
# (PyPI has ament_flake8, ament_pep257, ament_cppcheck, ament_cpplint, ament_uncrustify,
# ament_cmake_pytest and ament_cmake_gtest, and their ament_cmake_* wrappers).
NOT_ON_PYPI = frozenset(
    {
        "ament_lint_auto",
        "ament_lint_common",
        "ament_copyright",
        "ament_cmake_copyright",
        "ament_xmllint",
        "ament_cmake_xmllint",
        "ament_lint_cmake",
        "ament_cmake_lint_cmake",
    }
)


# <export><espdock_host_tests>DIR</espdock_host_tests></export> in a firmware package: a CMake
# project of host tests (its logic built with the host's compiler), relative to the package.
HOST_TESTS_TAG = "espdock_host_tests"


def host_tests_dir(package_dir: Path) -> Path | None:
    """The host tests a firmware package's package.xml declares, None when it declares none."""
    from catkin_pkg.package import parse_package

    exports = {e.tagname: (e.content or "").strip() for e in parse_package(str(package_dir / "package.xml")).exports}
    if not exports.get(HOST_TESTS_TAG):
        return None
    source = package_dir / exports[HOST_TESTS_TAG]
    # Missing, CMake's cwd was, which Popen said as "cmake is not installed"; without a
    # CMakeLists.txt, CMake failed and its failure counted as the tests'.
    problem = (
        "which is not a directory of"
        if not source.is_dir()
        else "which holds no CMakeLists.txt, in"
        if not (source / "CMakeLists.txt").is_file()
        else None
    )
    if problem is not None:
        raise WorkspaceError(
            f"{package_dir.name}'s package.xml declares its host tests in {exports[HOST_TESTS_TAG]} "
            f"(<{HOST_TESTS_TAG}>), {problem} {package_dir}",
            "Name the directory that holds their CMakeLists.txt, relative to the package.",
        )
    return source


def pytest_not_asked_for(package_dir: Path) -> bool:
    """Whether the ament_python package at PACKAGE_DIR has pytest files (test/test_*.py) that colcon
    will not run: colcon runs pytest only where setup.py's tests_require or a `test` extra names it
    (as `ros2 pkg create` writes it), else unittest, which collects no pytest function."""
    tests = [p for d in ("test", "tests") for p in (package_dir / d).glob("test_*.py")]
    if not tests:
        return False
    declared = " ".join(
        (package_dir / name).read_text(errors="replace")
        for name in ("setup.py", "setup.cfg")
        if (package_dir / name).is_file()
    )
    return "pytest" not in declared


# Where `espdock test` builds a firmware package's host tests and writes their results, per package
# (as colcon's build base has it: <package>/host_tests, <package>/test_results/<package>/).
HOST_TESTS_BASE = "build/espdock-host-tests"


def host_test_steps(source: Path, build: Path, junit: Path) -> tuple[tuple[str, ...], ...]:
    """The commands that build SOURCE's host tests in BUILD and run them, JUnit results in JUNIT:
    the same for `espdock test` and the colcon extension's test task."""
    return (
        ("cmake", "-S", str(source), "-B", str(build)),
        ("cmake", "--build", str(build)),
        ("ctest", "--test-dir", str(build), "--output-on-failure", "--output-junit", str(junit)),
    )


def host_tests_failed(argv: tuple[str, ...], code: int, junit: Path) -> bool | None:
    """After a step of host_test_steps: None to go on, False when a test failed (a result, in the
    JUnit file, as colcon's ctest step has it), True when the tests could not run."""
    if code == 0:
        return None
    return not (argv[0] == "ctest" and junit.is_file())


def run_host_tests(
    name: str, package_dir: Path, base: Path, on_line: Callable[[str], None], owner: tuple[int, int] | None = None
) -> int | None:
    """Build and run package NAME's (in PACKAGE_DIR) declared host tests under BASE/<package> with the host's CMake and
    compiler, as plain `colcon test` does; None when it declares none, else the failing step's exit
    code when they could not run (0 when they ran, passing or not: the JUnit file says). Run by
    root, as OWNER (the workspace's user), as the build containers are: the package's own code
    runs outside any container here."""
    source = host_tests_dir(package_dir)
    if source is None:
        return None
    build, junit = base / name / "host_tests", base / name / "test_results" / name / "host_tests.xml"
    junit.unlink(missing_ok=True)
    junit.parent.mkdir(parents=True, exist_ok=True)
    as_owner: dict[str, Any] = {}
    if owner is not None and os.geteuid() == 0 and owner[0] != 0:
        for path in (base.parent, base, *(base / name).rglob("*"), base / name):
            if path.lstat().st_uid == 0:
                os.chown(path, *owner, follow_symlinks=False)
        # Their HOME too (root's stayed: a test writing a cache under it failed, where it had not as root).
        home = _home_of(owner[0])
        env = {**os.environ, "HOME": home} if home else None
        as_owner = {"user": owner[0], "group": owner[1], "extra_groups": [], "env": env}
    for argv in host_test_steps(source, build, junit):
        try:
            process = subprocess.Popen(
                argv,
                cwd=source,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
                errors="replace",
                **as_owner,
            )
        except FileNotFoundError:
            raise DependencyError(
                f"{argv[0]} is not installed: the host tests of {name} ({source}) need CMake and a C/C++ compiler",
                "Install cmake and g++ (apt install cmake g++), or test other packages (`espdock test PKG...`).",
            ) from None
        assert process.stdout is not None
        for line in process.stdout:
            on_line(line.rstrip("\n"))
        code = process.wait()
        failed = host_tests_failed(argv, code, junit)
        if failed is not None:
            return code if failed else 0
    return 0


def _home_of(uid: int) -> str | None:
    try:
        return pwd.getpwuid(uid).pw_dir
    except KeyError:
        return None


def check_test_args(args: Iterable[str] | None) -> tuple[str, ...]:
    """ARGS for `colcon test`, by the rules of `espdock build -- ...` (espdock.ros.colcon), less
    colcon build's own options."""
    checked = check_colcon_args(args, "test")
    for arg in checked:
        option = arg.split("=", 1)[0]
        if not arg.startswith("--") or len(option) <= 3:
            continue
        if (building := full_option(option, BUILD_ONLY)) is not None:
            if building == "--continue-on-error":
                hint = "Leave it out: colcon test goes on past failing tests (`--abort-on-error` stops at the first)."
            else:
                hint = (
                    f"espdock test builds with the options of the last `espdock build`: pass it there "
                    f"(`espdock build -- {building} ...`), then run `espdock test`."
                )
            raise ConfigError(f"colcon option {option} is one of colcon build's, which colcon test does not take", hint)
    return checked


def check_testable(packages: Mapping[str, frozenset[str]], flavour: str) -> None:
    """Refuse, before anything runs, packages whose tests need what the FLAVOUR image cannot have
    (PACKAGES: name -> every dependency its package.xml names)."""
    if flavour != "wheels":
        return
    refused = {name: sorted(depends & NOT_ON_PYPI) for name, depends in packages.items() if depends & NOT_ON_PYPI}
    if refused:
        # `ros2 pkg create` writes ament_copyright (ament_python) or ament_lint_auto (ament_cmake)
        # into every package: the ways out name what to type, or to remove.
        raise DependencyError(
            f"{len(refused)} package(s) have tests that need ament packages PyPI does not carry, so the wheels ROS "
            "image cannot run them:\n" + "\n".join(f"  {name}: {', '.join(keys)}" for name, keys in refused.items()),
            'Test them on the official ROS image (ros_image = "official" in espdock.toml), which has ament\'s '
            f"linters; or test the others (`espdock test -- --packages-skip {' '.join(refused)}`); or drop those "
            "test_depends from the package.xml with the tests that use them (test/test_copyright.py, the "
            "ament_lint_auto lines in CMakeLists.txt's `if(BUILD_TESTING)`).",
        )


@dataclass(frozen=True)
class ColconTest:
    """colcon test of PACKAGES in IMAGE (the test build's), with the workspace sourced, in the
    colcon root."""

    image: str
    packages: tuple[str, ...]
    sources: tuple[tuple[str, str], ...] = ()
    colcon_args: tuple[str, ...] = ()
    defaults_file: str | None = None
    name: str = "colcon test"

    def argv(self, source: bool = True) -> tuple[str, ...]:
        """The container's command: the options are sh's positional parameters, never shell text.
        SOURCE: source the workspace first and write what that gave to SOURCED_DUMP (else the
        environment the container gets is the sourced one already, see SourcedEnv)."""
        options = (
            "--base-paths", *(rel for _, rel in self.sources), "--build-base", ROS_BUILD_BASE,
            "--event-handlers", "console_direct+", "console_start_end+", "summary+",
            "--packages-select", *self.packages, *without_leaving_out(self.colcon_args), *NONE_LEFT_OUT,
        )  # fmt: skip
        if not source:
            return ("colcon", "test", *options)
        # Sourced as colcon's own setup script is from sh, which cannot find its own path.
        script = (
            'COLCON_CURRENT_PREFIX="$PWD/install"; export COLCON_CURRENT_PREFIX; . install/local_setup.sh; '
            f'unset COLCON_CURRENT_PREFIX; env -0 > {SOURCED_DUMP}; exec colcon test "$@"'
        )
        return ("sh", "-c", script, "colcon-test", *options)


# What sourcing the workspace (install/local_setup.sh) gives the tests' environment: recorded by a
# run that sourced it, then passed as the container's environment while the install tree, the
# image and what espdock sets are the same. Sourcing starts a Python process that reads every
# package's hooks: 0.4 s of a 5-package workspace's 3 s `espdock test`, on every run.
SOURCED_ENV = "build/.espdock-test-env.json"
# Where the container that sources writes what it got (`env -0`), relative to the colcon root.
SOURCED_DUMP = "build/.espdock-test-env.dump"
# What reaches the tests from the caller's environment, as it reaches a native `colcon test`: a CI
# job's own DDS domain, discovery and middleware.
TEST_PASSED_ENV = (
    "ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS", "ROS_LOCALHOST_ONLY", "RMW_IMPLEMENTATION",
)  # fmt: skip
_DISCOVERY = frozenset({"ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS", "ROS_LOCALHOST_ONLY"})
# Where the tests' nodes and launch files write their ROS logs (rcl's, launch.log), under the
# colcon root: in the container's own ~/.ros they went with the container.
ROS_TEST_LOGS = "log/ros"
# Set per container by the engine or the shell, or per run by espdock (tests_env), not by sourcing.
NOT_SOURCED = frozenset({"HOSTNAME", "PWD", "OLDPWD", "SHLVL", "_", *TEST_PASSED_ENV, "ROS_LOG_DIR"})


def tests_env(env: Mapping[str, str], colcon_root: str) -> tuple[tuple[str, str], ...]:
    """The tests' ROS settings: what TEST_PASSED_ENV names from ENV, their log dir under
    COLCON_ROOT (the container's path), and without a discovery setting of the caller's, discovery
    on the container's own loopback. The test containers share the engine's bridge network, where
    DDS discovery reaches every container: two CI jobs' tests heard each other, and ament's
    isolated tests (domain_coordinator, which reserves a domain by a port of the container's own
    network) took the same domain in both."""
    values = {name: env[name] for name in TEST_PASSED_ENV if env.get(name)}
    # ROS_LOCALHOST_ONLY=0 (an old line of a shell's rc file) says nothing: rcl takes it as unset.
    if not _DISCOVERY & {name for name in values if (name, values[name]) != ("ROS_LOCALHOST_ONLY", "0")}:
        values["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    values["ROS_LOG_DIR"] = posixpath.join(colcon_root, ROS_TEST_LOGS)
    return tuple(sorted(values.items()))


@dataclass(frozen=True)
class SourcedEnv:
    """The environment of colcon test in IMAGE with ENV (what espdock sets) once the workspace at
    ROOT (the colcon root, on the host) is sourced, as recorded there."""

    root: Path
    image: str
    env: tuple[tuple[str, str], ...]

    def key(self) -> str | None:
        """What the sourced environment follows from; None when there is nothing to source."""
        install = self.root / "install"
        if not (install / "local_setup.sh").is_file():
            return None
        inputs = [self.image, sorted(self.env), listing_digest(install)]
        return hashlib.sha256(json.dumps(inputs).encode()).hexdigest()

    def recorded(self, key: str | None) -> tuple[tuple[str, str], ...] | None:
        """The environment recorded for KEY, None when none is (source in the container)."""
        try:
            data = json.loads((self.root / SOURCED_ENV).read_text())
        except (OSError, ValueError):
            return None
        if key is None or not isinstance(data, dict) or data.get("key") != key:
            return None
        return tuple((name, value) for name, value in data["env"])

    def forget(self) -> None:
        """Before a run that sources: neither the record for other inputs nor a dump an earlier
        run left (killed before it read it) may be taken for this run's."""
        for rel in (SOURCED_ENV, SOURCED_DUMP):
            (self.root / rel).unlink(missing_ok=True)

    def record(self, key: str) -> Path | None:
        """Record what the container that sourced wrote, for KEY; the file written, None when it
        wrote nothing usable."""
        dump = self.root / SOURCED_DUMP
        try:
            text = dump.read_bytes().decode()
        except (OSError, UnicodeDecodeError):
            return None
        finally:
            dump.unlink(missing_ok=True)
        pairs = [item.split("=", 1) for item in text.split("\0") if "=" in item]
        env = [[name, value] for name, value in pairs if name not in NOT_SOURCED]
        if not any(name == "COLCON_PREFIX_PATH" for name, _ in env):
            return None  # cut short: not what sourcing gave
        durable.write_text(self.root / SOURCED_ENV, json.dumps({"key": key, "env": env}) + "\n")
        return self.root / SOURCED_ENV


@dataclass
class PackageResults:
    """What one package's tests did, as its result files say."""

    package: str
    tests: int = 0
    failed: int = 0
    errored: int = 0
    skipped: int = 0
    files: list[Path] = field(default_factory=list)
    # The failing and erroring test cases, as classname.name; those of them that errored (an
    # exception outside the test's assertions: a fixture, a setup) besides.
    failing: list[str] = field(default_factory=list)
    erroring: set[str] = field(default_factory=set)
    # The CTest results file counted besides (not JUnit), and how many tests it counted.
    ctest_file: Path | None = None
    ctest_tests: int = 0

    @property
    def passed(self) -> int:
        return self.tests - self.failed - self.errored - self.skipped

    @property
    def ok(self) -> bool:
        return not (self.failed or self.errored)


def _count(suite: Element, results: PackageResults) -> None:
    # As colcon-test-result's xunit parser: the suite's attributes, `tests` and `failures` required.
    counts = {}
    for attribute in ("tests", "failures", "errors", "skip", "skipped", "disabled"):
        value = suite.attrib.get(attribute)
        if value is None and attribute in ("tests", "failures"):
            raise ValueError(f"no {attribute} attribute")
        counts[attribute] = int(value or 0)
    results.tests += counts["tests"]
    results.failed += counts["failures"]
    results.errored += counts["errors"]
    results.skipped += counts["skip"] + counts["skipped"] + counts["disabled"]
    for case in suite.iter("testcase"):
        outcomes = {child.tag for child in case}
        if outcomes & {"failure", "error"}:
            name = ".".join(part for part in (case.attrib.get("classname"), case.attrib.get("name")) if part)
            results.failing.append(name)
            if "failure" not in outcomes:
                results.erroring.add(name)


def read_results(build_base: Path, packages: Iterable[str]) -> dict[str, PackageResults]:
    """Each package's results from the xUnit files under BUILD_BASE/<package> (dot dirs skipped)."""
    found = {}
    for package in packages:
        results = PackageResults(package)
        root = build_base / package
        for dirpath, dirnames, filenames in os.walk(root):
            dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
            for filename in sorted(f for f in filenames if f.endswith(".xml")):
                path = Path(dirpath) / filename
                try:
                    tree = ElementTree().parse(path)
                    suites = [tree] if tree.tag == "testsuite" else [s for s in tree if s.tag == "testsuite"]
                    if tree.tag not in ("testsuite", "testsuites"):
                        continue
                    partial = PackageResults(package)
                    for suite in suites:
                        _count(suite, partial)
                except (ParseError, ValueError, OSError):
                    continue  # not an xUnit file (colcon-test-result skips these too)
                results.tests += partial.tests
                results.failed += partial.failed
                results.errored += partial.errored
                results.skipped += partial.skipped
                results.failing += partial.failing
                results.erroring |= partial.erroring
                results.files.append(path)
        _count_ctest(root, results)
        found[package] = results
    return found


def _count_ctest(root: Path, results: PackageResults) -> None:
    """Add the latest CTest Test.xml under ROOT (Testing/TAG names it), as colcon-cmake counts it."""
    tag = root / "Testing" / "TAG"
    try:
        latest = root / "Testing" / tag.read_text().splitlines()[0] / "Test.xml"
        site = ElementTree().parse(latest)
    except (OSError, IndexError, ParseError):
        return
    children = list(site)
    if site.tag != "Site" or len(children) != 1 or children[0].tag != "Testing":
        return
    tests = [child for child in children[0] if child.tag == "Test"]
    for test in tests:
        status = test.attrib.get("Status")
        if status == "failed":
            results.failed += 1
            results.failing.append(f"ctest {test.findtext('Name')}")
        elif status == "notrun":
            results.skipped += 1
        elif status != "passed":
            results.errored += 1
    results.tests += len(tests)
    results.ctest_file, results.ctest_tests = latest, len(tests)


def prepare_results(destination: Path, owner: tuple[int, int], packages: Iterable[str]) -> None:
    """Before a run with `--results DESTINATION`: it can be written (its directories made, as root
    OWNER's), and for PACKAGES, and the last run's copies are gone (forget_collected)."""
    prepare_output(destination, owner, "--results", directory=True)
    try:
        forget_collected(destination)
    except PermissionError as exc:
        raise permission_error(exc) from None
    for package in packages:
        if (destination / package).exists():
            prepare_output(destination / package, owner, "--results", directory=True)


def copy_results(
    results: Mapping[str, PackageResults], bases: Mapping[str, Path], destination: Path, owner: tuple[int, int]
) -> tuple[int, EspdockError | None]:
    """collect_results of each package from its build base in BASES: how many files, and the error
    that stopped it (checked before the run, so something changed since)."""
    written = 0
    try:
        for base in dict.fromkeys(bases.values()):
            here = {name: result for name, result in results.items() if bases[name] == base}
            written += len(collect_results(here, base, destination, owner))
    except PermissionError as exc:
        return written, permission_error(exc)
    except OSError as exc:
        return written, WorkspaceError(f"could not copy the results to {destination}: {exc.strerror or exc}")
    return written, None


def clear_results(build_base: Path, packages: Iterable[str]) -> None:
    """Remove the result files an earlier run left for PACKAGES: a test that no longer exists
    must not be counted again (colcon's pytest step rewrites its file, CTest's tests theirs).
    CTest's TAG too, which names the Test.xml counted: colcon runs no CTest in a package that has
    no test left ("No ctests found"), and the last run's failures were counted again."""
    for package in packages:
        for path in read_results(build_base, [package])[package].files:
            path.unlink(missing_ok=True)
        (build_base / package / "Testing" / "TAG").unlink(missing_ok=True)


# What the last `--results DIR` copied into DIR, one path under it per line.
RESULTS_RECORD = ".espdock-results"


def collect_results(
    results: Mapping[str, PackageResults], build_base: Path, destination: Path, owner: tuple[int, int]
) -> list[Path]:
    """Copy every result file into DESTINATION/<package>/, named after its place in the build dir,
    and add it to DESTINATION's record (forget_collected). As root, what it writes and the
    directories it makes belong to OWNER (`sudo espdock test`)."""
    written = []
    for package, result in results.items():
        for path in result.files:
            rel = path.relative_to(build_base / package).as_posix().replace("/", "-")
            target = destination / package / rel
            make_dirs_for(target.parent, owner)
            shutil.copyfile(path, target)
            give_to(target, owner)
            written.append(target)
    if written:
        record = destination / RESULTS_RECORD
        made = not record.exists()
        with record.open("a") as lines:
            lines.writelines(f"{target.relative_to(destination).as_posix()}\n" for target in written)
        if made:
            give_to(record, owner)
    return written


def forget_collected(destination: Path) -> None:
    """Remove the files an earlier `--results DESTINATION` copied there, before this run's: on a CI
    runner that keeps its directories, the packages and tests this run does not test would
    otherwise be reported again as its own, and a run that fails before its tests would leave
    the last run's results standing. Only what the record names goes."""
    record = destination / RESULTS_RECORD
    try:
        names = record.read_text().splitlines()
    except (FileNotFoundError, NotADirectoryError):
        return
    for name in names:
        parts = Path(name).parts
        if len(parts) != 2 or ".." in parts:
            continue  # the record only ever names <package>/<file>
        (destination / name).unlink(missing_ok=True)
        with contextlib.suppress(OSError):  # holds other files still
            (destination / parts[0]).rmdir()
    record.unlink()


def not_left_out(
    packages: list[Package], every: tuple[Package, ...], colcon_args: tuple[str, ...], build_base: Path
) -> tuple[list[Package], list[str]]:
    """PACKAGES but those COLCON_ARGS (`colcon test`'s options) skip, and the names of those: colcon
    would run none of their tests and find no result files (EVERY: the workspace's packages, whose
    dependencies --packages-skip-up-to and -by-dep follow; BUILD_BASE: where the last tests' results
    are, which --packages-skip-test-passed reads). Their test dependencies are not asked for, and
    their results are kept."""
    skipped = left_out(colcon_args, {p.name: p.depends for p in every}, build_base)
    return [p for p in packages if p.name not in skipped], [p.name for p in packages if p.name in skipped]
