"""colcon's side of a ROS build: the options passed through after `--` and the settings files colcon
reads (colcon.meta, its defaults files). What espdock records of a build's options and install
kinds is in trees; what colcon said of a run (its usage errors, event log, failures), in colcon_log.

Where colcon (colcon-core, colcon-defaults, colcon-metadata) looks, as the build container sees it
(colcon runs in the colcon root with HOME=/tmp):
- `./colcon.meta` in the colcon root (or the files `--metas` names): read there, by colcon itself;
- `./colcon_defaults.yaml` in the colcon root: read there, by colcon itself;
- the user's defaults file, COLCON_DEFAULTS_FILE, else $COLCON_HOME/defaults.yaml, else
  ~/.colcon/defaults.yaml: on the host, so espdock mounts it and points COLCON_DEFAULTS_FILE at it;
- a package's own `colcon.pkg` (and `colcon.meta`, which colcon reads only through `--metas`):
  part of the package's sources, so its stamp covers them.
User metadata ($COLCON_HOME/metadata/*.meta) is not forwarded: the container does not see it.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import os
import posixpath
import pwd
import re
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

from espdock.errors import ConfigError, WorkspaceError
from espdock.layout import ROS_BUILD_BASE

WORKSPACE_META = "colcon.meta"
WORKSPACE_DEFAULTS = "colcon_defaults.yaml"
# Where the user's defaults file is mounted in the build container.
DEFAULTS_MOUNT = "/run/espdock/colcon-defaults.yaml"
# setuptools' build and install copy a file only when it is newer than its last copy: a source
# put back with an older time (`git archive | tar -x`, `cp -p`, a restored backup) left the newer
# code installed, while espdock, which decides by content, said it built it. setuptools'
# distutils reads this extra config file (DIST_EXTRA_CONFIG), which has them copy every file:
# each copying command's own `force` (the install command's would reach `develop` too, whose
# --symlink-install then failed on the ament index).
SETUPTOOLS_CONFIG = "/run/espdock/setuptools.cfg"
SETUPTOOLS_FORCE = "".join(
    f"[{command}]\nforce = 1\n"
    for command in ("build_py", "build_scripts", "install_lib", "install_data", "install_scripts")
).encode()
# rosidl_generator_py hands the Python package it generates to ament_python_install_package, whose
# copy (or symlink) of it for `setup.py egg_info` waits for no generator: under make -j the
# egg-info's SOURCES.txt listed the generated modules or not by the build's timing, and two builds
# of one commit installed different files (2 of 8 fresh clones). Every package's top-level project()
# includes this (CMAKE_PROJECT_TOP_LEVEL_INCLUDES, CMake 3.24 and newer; older ones ignore it): at the
# end of its CMakeLists it has each such copy wait for the package's Python generators. It lives in
# the build base, where every container of the workspace sees it: CMake reads it again whenever it
# configures a build dir again (a `colcon build` in `espdock shell`, which builds there too).
EGG_INFO_ORDER = ".espdock-egg-info-order.cmake"
EGG_INFO_ORDER_CMAKE = b"""\
function(_espdock_egg_info_after_generators)
  get_property(targets DIRECTORY "${CMAKE_SOURCE_DIR}" PROPERTY BUILDSYSTEM_TARGETS)
  set(generators "")
  foreach(target IN LISTS targets)
    if(target MATCHES "^(.+)__rosidl_generator_py$")
      if(TARGET "${CMAKE_MATCH_1}__py")
        list(APPEND generators "${CMAKE_MATCH_1}__py")
      endif()
    endif()
  endforeach()
  if(generators)
    foreach(target IN LISTS targets)
      if(target MATCHES "^ament_cmake_python_(copy|symlink)_")
        add_dependencies("${target}" ${generators})
      endif()
    endforeach()
  endif()
endfunction()
cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL _espdock_egg_info_after_generators)
"""


def egg_info_order_define(workdir: str) -> str:
    """The CMake argument that has each package include EGG_INFO_ORDER, from the build base under the
    colcon root WORKDIR (in the container)."""
    return f"-DCMAKE_PROJECT_TOP_LEVEL_INCLUDES={posixpath.join(workdir, ROS_BUILD_BASE, EGG_INFO_ORDER)}"


def with_egg_info_order(args: tuple[str, ...], define: str, defaults: tuple[str, ...] = ()) -> tuple[str, ...]:
    """ARGS with DEFINE (egg_info_order_define) first among the CMake arguments colcon keeps, those of
    the last `--cmake-args` (one of the user's own setting of CMAKE_PROJECT_TOP_LEVEL_INCLUDES comes
    after it, and wins). DEFAULTS: the cmake-args of the user's colcon defaults file, which a
    `--cmake-args` given would replace."""
    args = _spelt_apart(args)
    if (index := _last_cmake_args(args)) is not None:
        return (*args[: index + 1], define, *args[index + 1 :])
    return (*args, "--cmake-args", define, *defaults)


def _last_cmake_args(args: tuple[str, ...]) -> int | None:
    """Where the last `--cmake-args` of ARGS is: colcon keeps only the last one's values, and what
    joined the first (`-- --cmake-args -DX=1 --cmake-args -DY=2`) never reached CMake."""
    return max((index for index, arg in enumerate(args) if arg == "--cmake-args"), default=None)


_OWN = "espdock decides it"
# Options espdock itself sets or relies on, with why; colcon accepts unique prefixes of options.
REFUSED = {
    "--base-paths": "espdock points colcon at the selected packages",
    "--paths": "espdock points colcon at the selected packages",
    "--build-base": "espdock keeps its own build base, build/espdock-ros (apart from a native build's CMake caches)",
    "--install-base": "espdock installs into install/ of the colcon root, where its stamps and manifest look",
    "--merge-install": "espdock reads each package's install/<package> (stamps, manifest, runtime image)",
    "--event-handlers": "espdock reads colcon's console output and its event log",
    "--log-base": "espdock reads colcon's event log in log/",
    # A build's as well: ament_cmake keeps it in the CMake cache, where the next tests' results go.
    "--test-result-base": f"espdock reads the test results in {ROS_BUILD_BASE}/ of the colcon root",
}
SELECTING = (
    "--packages-select", "--packages-select-regex", "--packages-select-by-dep", "--packages-select-build-failed",
    "--packages-select-test-failures", "--packages-up-to", "--packages-up-to-regex", "--packages-above",
    "--packages-above-and-dependencies", "--packages-above-depth", "--packages-start", "--packages-end",
)  # fmt: skip
for _option in SELECTING:
    REFUSED[_option] = (
        "espdock selects the packages: name them on its command line (`espdock build PKG...`, `espdock test PKG...`)"
    )
# colcon's own ways of running again what failed, which espdock's selection leaves out.
REFUSED["--packages-select-test-failures"] += (
    "; `espdock test -- --packages-skip-test-passed` tests again only what did not pass last time"
)
REFUSED["--packages-select-build-failed"] += (
    "; `espdock build` builds again only what failed or changed, and `-- --packages-skip-build-finished` "
    "what did not finish"
)
# Options that change which packages run or how they are scheduled, not what a build produces:
# left out of the stamps, so adding --parallel-workers does not rebuild everything. The value is
# whether the option takes values.
SCHEDULING = {
    "--parallel-workers": True,
    "--executor": True,
    "--continue-on-error": False,
    "--packages-skip": True,
    "--packages-skip-regex": True,
    "--packages-skip-by-dep": True,
    "--packages-skip-up-to": True,
    "--packages-skip-build-finished": False,
    "--packages-skip-test-passed": False,
    "--packages-ignore": True,
    "--packages-ignore-regex": True,
}


# colcon's options of its build and test verbs (colcon-core's and the extensions' a ROS install
# has) that neither REFUSED nor SCHEDULING names: a habit typed before espdock's `--`.
COLCON_ONLY = (
    "--symlink-install", "--cmake-args", "--ament-cmake-args", "--catkin-cmake-args", "--cmake-target",
    "--cmake-target-skip-unavailable", "--cmake-clean-cache", "--cmake-clean-first", "--cmake-force-configure",
    "--mixin", "--mixin-files", "--metas", "--allow-overriding", "--log-level", "--pytest-args",
    "--pytest-with-coverage", "--ctest-args", "--retest-until-fail", "--retest-until-pass", "--abort-on-error",
    "--return-code-on-test-failure", "--python-testing",
)  # fmt: skip


def misplaced_option(option: str, verb: str) -> str | None:
    """What to say of OPTION, given to `espdock VERB` before its `--`, where it is colcon's (None
    where it is not): where it goes, or why espdock does not pass it."""
    if option in REFUSED:
        return f"{option} is colcon's option, which espdock {verb} does not pass on: {REFUSED[option]}"
    if option in SCHEDULING or option in COLCON_ONLY:
        return (
            f"{option} is colcon's option, not espdock {verb}'s: give it after `--`, which passes what follows "
            f"to `colcon {verb}` (`espdock {verb} [PKG...] -- {option}{' ...' if option != SPELT_OUT else ''}`)"
        )
    return None


# Per verb: an example of options after `--`, and of the options that are allowed there.
_VERB_EXAMPLES = {
    "build": (
        "--cmake-args -DBUILD_TESTING=OFF",
        "about how packages are built, e.g. `--cmake-args ...`, `--packages-skip X`, `--continue-on-error`",
    ),
    "test": (
        "--pytest-args -k fast",
        "about how the tests run, e.g. `--pytest-args ...`, `--ctest-args ...`, `--packages-skip X`, "
        "`--retest-until-fail N`",
    ),
}


def check_colcon_args(args: Iterable[str] | None, verb: str = "build") -> tuple[str, ...]:
    """ARGS for `colcon VERB` (None: no `--` was given), refusing an empty `--` and what
    conflicts with what espdock controls."""
    if args is None:
        return ()
    args = tuple(args)
    example, allowed = _VERB_EXAMPLES[verb]
    if not args:
        raise ConfigError(
            f"nothing after `--`: it passes the options that follow it to `colcon {verb}`",
            f"Add them, e.g. `espdock {verb} -- {example}`, or leave out the `--`.",
        )
    if not args[0].startswith("-"):
        # colcon takes no positional argument: after espdock's own options, the word went into
        # the last of them that takes values (--event-handlers, --packages-select).
        raise ConfigError(
            f"'{args[0]}' after `--` is no colcon option: what follows `--` goes to `colcon {verb}` as options",
            f"Name packages before the `--` (`espdock {verb} {args[0]}`); options after it, e.g. "
            f"`espdock {verb} -- {example}`.",
        )
    passing = False  # after a `--cmake-args` & co, whose values (`-DX=1`) begin with a dash
    for arg in args:
        if arg == "--":
            raise ConfigError(
                f"a second `--` after the first: what follows the first goes to `colcon {verb}` as options",
                f"Give colcon's options once, after one `--` (`espdock {verb} -- {example}`).",
            )
        if arg.startswith("--"):
            passing = _PASSED_ON.match(arg) is not None
        elif arg.startswith("-") and not passing:
            # colcon's argparse took it for a value of espdock's own --event-handlers before it.
            raise ConfigError(
                f"'{arg}' after `--` is no colcon option: what follows `--` goes to `colcon {verb}` as options",
                f"Give a tool's options after the colcon option that passes them on, e.g. "
                f"`espdock {verb} -- --cmake-args {arg}`.",
            )
    # colcon takes unique prefixes (`--symlink`): spelt out where espdock reads the option itself.
    args = tuple(SPELT_OUT if _option_name(arg) and _abbreviates(arg, SPELT_OUT) else arg for arg in args)
    for arg in args:
        option = _option_name(arg)
        if option is None:
            continue
        for refused, why in REFUSED.items():
            if refused == option or (len(option) > 2 and refused.startswith(option)):
                shown = option if refused == option else f"{option} ({refused})"
                raise ConfigError(
                    f"colcon option {shown} is not allowed after `--`: {why}",
                    f"Pass colcon only options {allowed}, `--parallel-workers N`.",
                )
    return args


# MAKEFLAGS' words that only say how many jobs make runs at once (`-j4`, `--jobs=4`, `-l3`), which
# colcon-cmake reads for its packages' builds: nothing they build differs by them.
_MAKE_JOBS = re.compile(r"^(-j\d*|--jobs(=\d+)?|-l[\d.]*|--load-average(=[\d.]+)?)$")


def make_jobs(env: Mapping[str, str]) -> str | None:
    """What the build container takes of ENV's MAKEFLAGS: its job limits, the way to build a C++
    package on a machine of little memory (colcon-cmake runs a compile per core otherwise); None
    where it has none. Its other words would change what is built, and stay out as the rest of
    the environment does."""
    kept = [word for word in env.get("MAKEFLAGS", "").split() if _MAKE_JOBS.match(word)]
    return " ".join(kept) or None


# The flag whose presence espdock reads (the install kind).
SPELT_OUT = "--symlink-install"


def _abbreviates(arg: str, option: str) -> bool:
    """Whether ARG is a prefix of OPTION colcon's argparse takes for it (`--s` too, unique there)."""
    return len(arg) > 2 and option.startswith(arg) and arg != option


def _option_name(arg: str) -> str | None:
    return arg.split("=", 1)[0] if arg.startswith("--") and len(arg) > 2 else None


def output_args(args: Iterable[str]) -> tuple[str, ...]:
    """ARGS without the scheduling options (SCHEDULING): what decides what colcon produces."""
    return _without(args, SCHEDULING)


def without_leaving_out(args: Iterable[str]) -> tuple[str, ...]:
    """ARGS without the options that leave packages out (LEAVING_OUT): for a colcon run given only
    the packages espdock chose by them (colcon warns of each one it was told to skip and has not)."""
    return _without(args, LEAVING_OUT)


def _without(args: Iterable[str], options: Iterable[str]) -> tuple[str, ...]:
    """ARGS without OPTIONS (of SCHEDULING) and their values."""
    options = frozenset(options)
    return tuple(arg for arg, option, _ in _walk(args) if option not in options)


def _walk(args: Iterable[str]) -> Iterator[tuple[str, str | None, bool]]:
    """Each of ARGS with the option of SCHEDULING it is or gives a value to, by its full name
    (colcon takes unique prefixes longer than `--x`, and `--option=value`), None for neither;
    and whether it is the option itself. As argparse reads them: what follows `--option=value`,
    or a flag, is no value of it."""
    current: str | None = None
    for arg in args:
        option = _option_name(arg)
        if option is not None or arg.startswith("-"):
            full = full_option(option, SCHEDULING) if option is not None else None
            yield arg, full, True
            current = full if full is not None and SCHEDULING[full] and "=" not in arg else None
        else:
            yield arg, current, False


def full_option(option: str, names: Iterable[str]) -> str | None:
    """The one of NAMES that OPTION is, or abbreviates uniquely as colcon's argparse takes it
    (more than `--x`); else None."""
    names = tuple(names)
    if option in names:
        return option
    matches = [name for name in names if name.startswith(option)]
    return matches[0] if len(matches) == 1 and len(option) > 3 else None


# colcon's options that leave packages out of a build (colcon-package-selection).
LEAVING_OUT = (
    "--packages-skip", "--packages-skip-regex", "--packages-skip-up-to", "--packages-skip-by-dep",
    "--packages-ignore", "--packages-ignore-regex",
    "--packages-skip-build-finished", "--packages-skip-test-passed",
)  # fmt: skip
# What those two read: the result of the package's last `colcon build` or `colcon test`, which
# colcon-package-selection keeps in its build dir ("0": it finished, or its tests passed).
_PREVIOUS = {"--packages-skip-build-finished": "colcon_build.rc", "--packages-skip-test-passed": "colcon_test.rc"}
# Those that take package names or patterns, given with none: on the command line they win over
# a defaults file's, which espdock applied in choosing the packages it gives colcon; colcon, shown
# only those, warned "ignoring unknown package" of each other package the file named.
NONE_LEFT_OUT = tuple(option for option in LEAVING_OUT if option not in _PREVIOUS)


def not_naming(args: Iterable[str], outside: Iterable[str], inside: Iterable[str]) -> tuple[str, ...]:
    """ARGS without the package names and patterns of NONE_LEFT_OUT's options that name only
    packages colcon is not shown (OUTSIDE: the workspace's packages a selection leaves out; INSIDE:
    those it shows), each such option kept (with no value left, it still wins over a defaults
    file's). `espdock build PKG` with a defaults file's skip of another package: colcon warned
    "ignoring unknown package". A name of no package stays, for colcon to warn of."""
    outside, inside = frozenset(outside), frozenset(inside)

    def names_only_outside(option: str, value: str) -> bool:
        if not option.endswith("-regex"):
            return value in outside
        try:
            return any(re.match(value, n) for n in outside) and not any(re.match(value, n) for n in inside)
        except re.error:
            return False

    kept: list[str] = []
    for arg, option, itself in _walk(args):
        if option not in NONE_LEFT_OUT:
            kept.append(arg)
        elif itself:
            # The option without a value it no longer has.
            named, _, value = arg.partition("=")
            kept.append(named if value and names_only_outside(option, value) else arg)
        elif not names_only_outside(option, arg):
            kept.append(arg)
    return tuple(kept)


def _option_values(args: Iterable[str]) -> dict[str, list[str]]:
    """The values ARGS give each option of LEAVING_OUT, by its full name."""
    values: dict[str, list[str]] = {}
    for arg, option, itself in _walk(args):
        if option in LEAVING_OUT:
            given = values.setdefault(option, [])
            if not itself:
                given.append(arg)
            elif "=" in arg:
                given.append(arg.partition("=")[2])
    return values


def closure(names: Iterable[str], depends: Mapping[str, Iterable[str]]) -> set[str]:
    """What NAMES depend on in DEPENDS (name -> its workspace dependencies), directly or not."""
    found, stack = set(), list(names)
    while stack:
        name = stack.pop()
        for dep in depends.get(name, ()):
            if dep not in found:
                found.add(dep)
                stack.append(dep)
    return found


def left_out(
    args: Iterable[str], depends: Mapping[str, Iterable[str]], build_base: Path | None = None
) -> frozenset[str]:
    """The packages of DEPENDS (name -> its workspace dependencies) that `colcon build ARGS` (or
    `colcon test ARGS`) does not build: skipped or ignored by name or pattern (re.match, as
    colcon), skipped up to (with their dependencies) or by dependency (the packages depending on
    them), and with BUILD_BASE (colcon's), those whose last build finished or whose last tests
    passed, where ARGS skip them."""
    values = _option_values(args)
    out = set(values.get("--packages-skip", [])) | set(values.get("--packages-ignore", []))
    patterns = values.get("--packages-skip-regex", []) + values.get("--packages-ignore-regex", [])
    try:
        out |= {name for name in depends if any(re.match(pattern, name) for pattern in patterns)}
    except re.error as exc:
        raise ConfigError(
            f"colcon option after `--` has a pattern that is no regular expression: {exc}",
            "Fix the pattern (colcon matches it with Python's re.match against package names).",
        ) from exc
    up_to = set(values.get("--packages-skip-up-to", []))
    out |= up_to | closure(up_to, depends)
    by_dep = set(values.get("--packages-skip-by-dep", []))
    out |= {name for name in depends if closure({name}, depends) & by_dep}
    for option, result in _PREVIOUS.items():
        if option in values and build_base is not None:
            out |= {name for name in depends if _read_stripped(build_base / name / result) == "0"}
    return frozenset(out & set(depends))


def passed_last_time(args: Iterable[str], names: Iterable[str], build_base: Path) -> frozenset[str]:
    """NAMES that `--packages-skip-test-passed` in ARGS leaves out: their last tests passed."""
    if "--packages-skip-test-passed" not in _option_values(args):
        return frozenset()
    return left_out(("--packages-skip-test-passed",), {name: () for name in names}, build_base)


def _read_stripped(path: Path) -> str | None:
    try:
        return path.read_text().strip()
    except OSError:
        return None


_BUILD_TESTING = re.compile(r"^-DBUILD_TESTING(:BOOL)?=", re.IGNORECASE)
# The options colcon passes on to a tool (cmake, ament-cmake, pytest, ctest), given with their value joined.
_PASSED_ON_JOINED = re.compile(r"^--[a-z-]+-args=")
# Those options, spelt out or abbreviated as colcon takes them (`--cmake-arg`).
_PASSED_ON = re.compile(r"^--[a-z-]+-a(r(gs?)?)?(=|$)")


def _spelt_apart(args: Iterable[str]) -> tuple[str, ...]:
    """ARGS with `--cmake-args=VALUE` (or any `--*-args=VALUE`) as `--cmake-args VALUE`, as argparse
    reads it: the value the one form holds is the other's first."""
    return tuple(part for arg in args for part in (arg.split("=", 1) if _PASSED_ON_JOINED.match(arg) else (arg,)))


def without_build_testing(args: tuple[str, ...]) -> tuple[str, ...]:
    """ARGS without their BUILD_TESTING setting: a test build configures the tests whatever the
    build before it did. The others as they were spelt: the options decide the stamps, and a test
    build's must be the plain build's (`--cmake-args=-DFOO=7` taken apart, each rebuilt the other's)."""
    kept = []
    for arg in args:
        if arg.startswith("--cmake-args=") and _BUILD_TESTING.match(arg.split("=", 1)[1].strip()):
            kept.append("--cmake-args")
        elif not _BUILD_TESTING.match(arg.strip()):
            kept.append(arg)
    return tuple(kept)


def sets_build_testing(args: Iterable[str]) -> bool:
    """Whether ARGS (colcon options) set BUILD_TESTING themselves (`--cmake-args -DBUILD_TESTING=ON`)."""
    return any(_BUILD_TESTING.match(arg.strip()) for arg in _spelt_apart(args))


def with_build_testing(
    args: tuple[str, ...], value: str, defaults: tuple[str, ...] = (), force: bool = False
) -> tuple[str, ...]:
    """ARGS with CMake packages configured with BUILD_TESTING=VALUE, unless ARGS set it (or the
    DEFAULTS, the cmake-args of the user's colcon defaults file, do, and not FORCE). Given each
    time: CMake keeps a cached value. colcon keeps the last `--cmake-args` only, and one on the
    command line replaces the defaults file's: the value joins the user's own, from either."""
    if sets_build_testing(args):
        return args
    # `--cmake-args=-DFOO=3` is the same option: a second `--cmake-args` replaced it (colcon keeps
    # the last), and FOO stayed as CMake had cached it, unsaid.
    args = _spelt_apart(args)
    if (index := _last_cmake_args(args)) is not None:
        return (*args[: index + 1], f"-DBUILD_TESTING={value}", *args[index + 1 :])
    if sets_build_testing(defaults) and not force:
        return args
    return (*args, "--cmake-args", *without_build_testing(defaults), f"-DBUILD_TESTING={value}")


# What _defaults_yaml gives for a text that is not YAML.
_NOT_YAML = object()


@functools.lru_cache(maxsize=8)
def _defaults_yaml(text: str) -> object:
    """A colcon defaults file's TEXT as YAML (_NOT_YAML where it is not), parsed once for the
    several readings of one file in a build's settings (its refused keys, its verb's options, its
    stamp): not to be changed by its readers."""
    import yaml

    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        return _NOT_YAML


def defaults_for(text: str, verb: str = "build") -> dict:
    """What a colcon defaults file (TEXT) sets for VERB ({} when nothing or not YAML: colcon
    refuses such a file itself, naming it)."""
    data = _defaults_yaml(text)
    said = data.get(verb) if isinstance(data, dict) else None
    return said if isinstance(said, dict) else {}


def defaults_with_mixins(colcon_root: Path, env: Mapping[str, str]) -> list[str]:
    """The colcon defaults files (as shown to the user) whose `build` verb names mixins: the build
    image has no colcon-mixin, and colcon skipped the key with a warning among its output, naming
    the container's path of the file."""
    user = user_defaults_file(env)
    return [
        str(shown)
        for path, shown in ((user, user), (colcon_root / WORKSPACE_DEFAULTS, WORKSPACE_DEFAULTS))
        if path.is_file() and "mixin" in defaults_for(path.read_text(errors="replace"))
    ]


def defaults_leaving_out(
    colcon_root: Path, env: Mapping[str, str], verb: str, given: Iterable[str] = ()
) -> tuple[str, ...]:
    """The options that leave packages out (LEAVING_OUT) the colcon defaults files set for VERB
    (the workspace's over the user's), as command-line options, but for those GIVEN (options on
    the command line, which win). espdock's checks read them as colcon does: a package a
    defaults file skips was refused for its dependencies, and `espdock test` of only it passed
    nothing."""
    said: dict = {}
    for path in (user_defaults_file(env), colcon_root / WORKSPACE_DEFAULTS):
        if path.is_file():
            said.update(defaults_for(path.read_text(errors="replace"), verb))
    named = {_option_name(arg) for arg in given}
    args: list[str] = []
    for option in (option for option in LEAVING_OUT if option not in named):
        value = said.get(option.removeprefix("--"))
        if isinstance(value, list) and value:
            args += [option, *(str(item) for item in value)]
        elif value is True:
            args.append(option)
    return tuple(args)


def _deciding_digest(text: str) -> bytes | None:
    """sha256 of what a colcon defaults file (TEXT) says that may decide a build's output, as read
    (its comments, layout and anchors aside): its `build` verb's options, but the SCHEDULING ones,
    which decide no stamp after `--` either (a file of `packages-skip` alone rebuilt every package,
    and taking it out, every package again; so did its `test` verb's options). None where that is
    nothing; the text's own digest where it is no YAML mapping (colcon refuses it, naming it)."""
    data = _defaults_yaml(text)
    if data is None:
        return None
    if not isinstance(data, dict):  # not YAML, or no mapping
        return hashlib.sha256(text.encode()).digest()
    build = data.get("build")
    if not isinstance(build, dict):
        return None if build is None else hashlib.sha256(json.dumps(build, default=str).encode()).digest()
    # symlink-install: as on the command line (read_colcon_settings).
    deciding = {key: value for key, value in build.items() if f"--{key}" not in SCHEDULING and key != "symlink-install"}
    if not deciding:
        return None
    try:
        return hashlib.sha256(json.dumps(deciding, sort_keys=True, default=str).encode()).digest()
    except TypeError:  # keys of more than one type, which sort_keys cannot order
        return hashlib.sha256(repr(deciding).encode()).digest()


def _cmake_args(build: Mapping) -> tuple[str, ...] | None:
    """The cmake-args a defaults file's `build` verb (BUILD) sets; None where it sets none."""
    args = build.get("cmake-args")
    return tuple(str(arg) for arg in args) if isinstance(args, list) else None


def meta_paths(args: Iterable[str]) -> tuple[str, ...]:
    """The colcon.meta files or dirs colcon reads for ARGS (relative to the colcon root):
    `--metas` replaces the default ./colcon.meta."""
    paths: list[str] = []
    given = False
    collecting = False
    for arg in args:
        if arg.startswith("-"):
            option = _option_name(arg)
            collecting = option is not None and "--metas".startswith(option) and len(option) > 3
            if collecting:
                given = True
                if "=" in arg:
                    paths.append(arg.split("=", 1)[1])
            continue
        if collecting:
            paths.append(arg)
    return tuple(paths) if given else (f"./{WORKSPACE_META}",)


def parse_meta(where: str, text: str) -> dict:
    """A colcon.meta file's content, read as colcon-metadata reads it (YAML, of which JSON is a
    part); exit 2 naming WHERE when it is not a colcon.meta."""
    import yaml  # rosdep's dependency; only workspaces with a colcon.meta need it

    try:
        try:
            data = yaml.safe_load(text) if text.strip() else {}
        except yaml.YAMLError as exc:
            raise ValueError(str(exc).replace("\n", " ")) from exc
        if not isinstance(data, dict):
            raise ValueError("the top level is not an object")
        for section in ("names", "paths"):
            if not isinstance(data.get(section, {}), dict):
                raise ValueError(f"'{section}' is not an object")
    except ValueError as exc:
        raise WorkspaceError(
            f"{where} is not a valid colcon.meta: {exc}",
            'colcon.meta is YAML (or JSON): {"names": {"<package>": {"cmake-args": [...]}}}. Fix it and run again.',
        ) from exc
    return data


def package_meta(metas: Mapping[str, dict], package: str, package_dir: str) -> dict:
    """What the colcon.meta files METAS (path relative to the colcon root -> content) say about
    PACKAGE, found by name or by its directory PACKAGE_DIR (relative to the colcon root)."""
    said: dict[str, object] = {}
    for where, data in metas.items():
        if package in data.get("names", {}):
            said[f"{where}:names"] = data["names"][package]
        for rel, value in data.get("paths", {}).items():
            if posixpath.normpath(posixpath.join(posixpath.dirname(where), rel)) == posixpath.normpath(package_dir):
                said[f"{where}:paths:{rel}"] = value
    return said


# Keys of a defaults file (per verb; colcon's option names without dashes) that move what
# espdock relies on. Checked by name in the text: espdock reads no YAML of its own.
_DEFAULTS_KEY = re.compile(r"^[\s{,]*['\"]?([a-z][a-z0-9-]*)['\"]?\s*:", re.MULTILINE)


# What espdock always gives on colcon's command line, which wins over any defaults file.
SET_ON_COMMAND_LINE = ("--base-paths", "--event-handlers")


def check_defaults(where: str, text: str) -> None:
    """Refuse a colcon defaults file that sets what espdock controls (exit 2 naming the file)."""
    refused = {name.removeprefix("--") for name in REFUSED if name not in SET_ON_COMMAND_LINE}
    for key in (*(match.group(1) for match in _DEFAULTS_KEY.finditer(text)), *_yaml_keys(text)):
        if key in refused:
            raise ConfigError(
                f"{where} sets {key}, which espdock controls: {REFUSED['--' + key]}",
                "Remove it from that file (or build with COLCON_DEFAULTS_FILE pointing at another).",
            )


def _yaml_keys(text: str) -> list[str]:
    """Every key of the YAML TEXT's mappings, at any depth: the flow style (`test: {test-result-base:
    x}`) sets a verb's options on the verb's line, which a look at each line's first key missed."""
    data = _defaults_yaml(text)
    keys: list[str] = []
    pending = [data]
    while pending:
        item = pending.pop()
        if isinstance(item, dict):
            keys += [str(key) for key in item]
            pending += list(item.values())
    return keys


def user_defaults_file(env: Mapping[str, str]) -> Path:
    """Where colcon reads the user's defaults: COLCON_DEFAULTS_FILE, else $COLCON_HOME/defaults.yaml,
    else ~/.colcon/defaults.yaml (colcon-defaults and colcon-core's command.py)."""
    if env.get("COLCON_DEFAULTS_FILE"):
        return Path(env["COLCON_DEFAULTS_FILE"])
    home = env.get("HOME") or os.path.expanduser("~")
    caller = env.get("SUDO_UID", "")
    if os.geteuid() == 0 and caller.isdigit() and caller != "0" and Path(home) == Path(pwd.getpwuid(0).pw_dir):
        # `sudo espdock build` builds for its caller (their files, their stamps): root's defaults
        # (sudo's HOME is root's) turned their --symlink-install off, and everything was built
        # again, then again by their own next build.
        with contextlib.suppress(KeyError):
            home = pwd.getpwuid(int(caller)).pw_dir
    return Path(env.get("COLCON_HOME") or os.path.join(home, ".colcon")) / "defaults.yaml"


@dataclass(frozen=True)
class ColconSettings:
    """The colcon options and settings files of a build, as they decide each package's stamp."""

    args: tuple[str, ...] = ()
    # Per package: a digest of the output-deciding options, the defaults files and what the
    # colcon.meta files say about it.
    digests: tuple[tuple[str, str], ...] = ()
    # The user's defaults file on the host, mounted into the build container; None: there is none.
    defaults_file: str | None = None
    # The settings files that were read (for --dry-run).
    files: tuple[str, ...] = ()
    # The cmake-args of `colcon build` the defaults files set (the workspace's over the user's).
    cmake_args: tuple[str, ...] = ()
    # Whether they turn `colcon build`'s symlink-install on.
    symlink_install: bool = False


def read_colcon_settings(
    colcon_root: Path, package_dirs: Mapping[str, Path], args: Iterable[str] | None, env: Mapping[str, str]
) -> ColconSettings:
    """Read and check the settings colcon will use for PACKAGE_DIRS (name -> directory), run in
    COLCON_ROOT with ARGS (None: no `--`); a malformed file or a refused option is exit 2 before
    anything runs."""
    args = check_colcon_args(args)
    args += defaults_leaving_out(colcon_root, env, "build", args)
    files: list[str] = []
    # The same options spelt either way (`--cmake-args=-DX=1`, `--cmake-args -DX=1`) build the same;
    # so does --symlink-install given or set in a defaults file (added below, once, where either has it).
    hashed = tuple(arg for arg in output_args(_spelt_apart(args)) if arg != SPELT_OUT)
    deciding: list[bytes] = []
    defaults: str | None = None
    cmake_args: tuple[str, ...] = ()
    symlink_install = False
    user = user_defaults_file(env)
    for path, shown in ((user, str(user)), (colcon_root / WORKSPACE_DEFAULTS, WORKSPACE_DEFAULTS)):
        if not path.is_file():
            continue
        text = path.read_text(errors="replace")
        check_defaults(shown, text)
        build = defaults_for(text)
        cmake_args = _cmake_args(build) or cmake_args
        symlink_install = build.get("symlink-install", symlink_install) is True
        if (decides := _deciding_digest(text)) is not None:
            deciding.append(f"{shown}\0".encode() + decides)
        files.append(shown)
        if path == user:
            defaults = str(path.resolve())
    # Last among the options, where `-- --symlink-install` alone has it: those builds' stamps stand.
    symlinked = symlink_install or SPELT_OUT in args
    common = hashlib.sha256(json.dumps((*hashed, SPELT_OUT) if symlinked else hashed).encode())
    for part in deciding:
        common.update(part)
    metas: dict[str, dict] = {}
    for given in meta_paths(args):
        rel = posixpath.join(given, WORKSPACE_META) if (colcon_root / given).is_dir() else given
        path = colcon_root / rel
        if path.is_file():
            metas[posixpath.normpath(rel)] = parse_meta(rel, path.read_text(errors="replace"))
            files.append(posixpath.normpath(rel))
    for directory in package_dirs.values():
        own = directory / WORKSPACE_META
        if own.is_file():
            parse_meta(str(own), own.read_text(errors="replace"))
    digests = []
    for name, directory in package_dirs.items():
        said = package_meta(metas, name, os.path.relpath(directory, colcon_root))
        digest = common.copy()
        digest.update(json.dumps(said, sort_keys=True).encode())
        digests.append((name, digest.hexdigest()))
    return ColconSettings(args, tuple(digests), defaults, tuple(files), cmake_args, symlink_install)
