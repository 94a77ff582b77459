"""Test dependencies: the packages' test_depend keys, through rosdep and the lock like the others,
but apart from the build's, and installed only into the image `espdock test` runs in.

rosdep.lock.json keeps them under "test" (same shape as the build's part: keys, apt, pip, its
own input digest), so a build never installs them and a change to them never makes the build
image stale. The test image is one layer over the build image: what that part names.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path

from espdock.build.steps import EnsureImage, ImageSpec, Plan, image_key
from espdock.ros import rosdeps
from espdock.ros.plan import ColconBuild
from espdock.ros.system_python import SystemPython
from espdock.ros.testing import NOT_ON_PYPI
from espdock.workspace import Package

SECTION = "test"
# Where the test image keeps what it installs (beside the build image's /opt/espdock/rosdep).
TEST_DIR = "/opt/espdock/rosdep-test"


# The rosdep keys ament's linters name as exec_depend in their package.xml (ament_lint 0.17,
# Jazzy), which their PyPI wheels do not install (they declare no dependency): on the wheels
# image they are the linters' own test keys too (the official image's apt packages bring them).
# ament_lint's pytest plugin registers the `linter` mark the linters' tests carry (pytest warned
# of an unknown mark at each of them, and `--strict-markers` failed them).
_FLAKE8 = (
    "python3-flake8", "python3-flake8-builtins", "python3-flake8-comprehensions", "python3-flake8-docstrings",
    "python3-flake8-import-order", "python3-flake8-quotes",
)  # fmt: skip
_LINTERS = {
    "ament_flake8": (*_FLAKE8, "ament_lint"),
    "ament_pep257": ("ament_lint", "pydocstyle"),
    "ament_cppcheck": ("cppcheck",),
    "ament_cpplint": (),
    "ament_uncrustify": ("uncrustify_vendor",),
}
# A CMake wrapper's one exec_depend is its linter: the wrapper's wheel alone (which the message
# wheels bring into the image) left CMake's `ament_cpplint()` "could not find program".
WHEELS_OMIT = {
    **_LINTERS,
    **{f"ament_cmake_{linter.removeprefix('ament_')}": (linter, *keys) for linter, keys in _LINTERS.items()},
}

# A vendor package's tool (uncrustify_vendor's uncrustify, which ament_uncrustify looks for on
# PATH) is found through its package's environment hook (PATH gets opt/<name>/bin), which
# nothing sources in the wheels venv: it is linked into the venv's bin/, where colcon looks.
VENDOR_TOOLS_ON_PATH = (
    'RUN for tool in "$VIRTUAL_ENV"/opt/*_vendor/bin/*; do '
    '[ -f "$tool" ] && [ ! -e "$VIRTUAL_ENV/bin/${tool##*/}" ] && ln -s "$tool" "$VIRTUAL_ENV/bin/"; done; true\n'
)


def _as_tests(packages: Iterable[Package], image: rosdeps.RosImage | None = None) -> tuple[Package, ...]:
    """PACKAGES with their test-only dependencies as their dependencies (rosdeps' functions then
    answer for the tests' keys), with what the wheels of those omit (WHEELS_OMIT)."""
    wheels = image is not None and image.flavour == "wheels"
    tested = []
    for p in packages:
        keys = set(p.test_only_depends)
        if wheels:
            keys.update(k for dep in p.test_only_depends for k in WHEELS_OMIT.get(dep, ()))
            # No wheel exists for these: `espdock test` refuses their packages before anything
            # runs (testing.check_testable), so they must not fail the lock of everyone else.
            keys -= NOT_ON_PYPI
        tested.append(dataclasses.replace(p, depends=frozenset(keys), test_only_depends=frozenset()))
    return tuple(tested)


def keys_for_tests(
    packages: Iterable[Package], image: rosdeps.RosImage, workspace: Iterable[str] = ()
) -> dict[str, tuple[str, ...]]:
    """Per ROS package: its test_depend keys that are neither workspace packages (PACKAGES' and
    those WORKSPACE names besides) nor in the image."""
    return rosdeps.needed_keys(_as_tests(packages, image), image, workspace)


def lock_test_part(lock: Mapping | None) -> dict | None:
    """The lock's test part, None when it has none."""
    part = (lock or {}).get(SECTION)
    return part if isinstance(part, dict) else None


def stale_reason(lock: Mapping | None, packages: Iterable[Package], image: rosdeps.RosImage, name: str) -> str | None:
    """Why LOCK's test part does not answer for the packages' test keys; None when it does."""
    needed = keys_for_tests(packages, image)
    part = lock_test_part(lock)
    if part is None:
        if not needed:
            return None
        said = [f"{package}'s tests need {', '.join(keys)}" for package, keys in sorted(needed.items())]
        why = "; ".join(said[:6]) + (f" (and {len(said) - 6} more)" if len(said) > 6 else "")
        return f"{name} is missing: {why}" if lock is None else f"{name} records no test dependencies: {why}"
    return rosdeps.stale_reason(part, needed, image, f"{name} (its test part)")


def resolve(
    packages: Iterable[Package],
    image: rosdeps.RosImage,
    root: Path,
    env: Mapping[str, str],
    uv: str,
    system: Callable[[], SystemPython] | None = None,
    ca_bundle: Path | None = None,
) -> dict:
    """The lock's test part: rosdep's rules for the test keys, as the image installs them."""
    part = rosdeps.resolve_workspace(_as_tests(packages, image), image, root, env, uv, system, ca_bundle)
    part.pop("format", None)
    part["made_by"] = "`espdock lock`: the packages' test_depend keys, installed only by `espdock test`"
    return part


def check_tests(
    selected: Iterable[Package], lock: Mapping | None, image: rosdeps.RosImage, every: Iterable[Package] = ()
) -> None:
    """Refuse (exit 2, before anything runs) packages whose test keys neither the image nor the
    lock's test part provides; on the wheels image the way out names the official one. EVERY:
    the workspace's packages, which a test_depend may name (a package of test helpers): `espdock
    test PKG` took one for a key missing from the lock, which `espdock lock` never added."""
    selected = tuple(selected)
    needed = keys_for_tests(selected, image, (p.name for p in every))
    rosdeps.check_dependencies(_as_tests(selected, image), needed, lock_test_part(lock), image, command="test")


def image_for_tests(build: ImageSpec, lock: Mapping | None, official: bool) -> ImageSpec | None:
    """The image `espdock test` builds and runs in: BUILD plus the lock's test part; None when
    the part installs nothing (the build image then serves)."""
    files = rosdeps.image_files(lock_test_part(lock))
    if not any(not line.startswith("#") for data in files.values() for line in data.decode().splitlines()):
        return None
    pip_option = " --break-system-packages" if official else ""
    dockerfile = (
        f"FROM {build.tag} AS test\n"
        f"COPY rosdep-test/ {TEST_DIR}/\n"
        f"RUN --mount=type=secret,id=ca_bundle sh /opt/espdock/rosdep-install.sh {TEST_DIR} python3{pip_option}\n"
    )
    if not official:
        dockerfile += VENDOR_TOOLS_ON_PATH
    context = {"Dockerfile": dockerfile.encode(), **{f"rosdep-test/{n}": d for n, d in files.items()}}
    key, inputs = image_key({**context, "build": build.key.encode()})
    return ImageSpec(
        repository=build.repository.removesuffix("-build") + "-test",
        key=key,
        dockerfile="Dockerfile",
        target="test",
        build_args=(),
        inputs=inputs,
        context=tuple(sorted(context.items())),
        origin=f"generated: {build.tag} plus the rosdep lock's test dependencies",
    )


def with_test_image(plan: Plan, lock: Mapping | None, official: bool) -> Plan:
    """PLAN (ending in its colcon build) building in the test image, made right before it."""
    build = next(step for step in plan.steps if isinstance(step, ColconBuild))
    base = next(s.spec for s in plan.steps if isinstance(s, EnsureImage) and s.spec.tag == build.image)
    spec = image_for_tests(base, lock, official)
    if spec is None:
        return plan
    steps = []
    for step in plan.steps:
        if step is build:
            steps += [EnsureImage(spec), dataclasses.replace(build, image=spec.tag)]
        else:
            steps.append(step)
    return Plan(plan.workspace, tuple(steps), plan.idf_images)
