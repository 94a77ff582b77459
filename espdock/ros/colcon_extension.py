"""colcon extensions: plain `colcon build` builds ESP-IDF firmware packages through espdock.

Registered as entry points of espdock's distribution, so `pip install espdock` beside colcon
is all it takes; where colcon runs in another Python (apt's colcon, espdock from pipx),
`espdock colcon-extension install` registers them there (espdock.ros.colcon_register).
A package.xml with <build_type>esp_idf</build_type> is a package of type `ros.esp_idf` (the
type colcon-ros would give it, so its augmentation adds the dependencies too), and its build
task runs `espdock build --only firmware PKG` (IDF container, micro-ROS image) in colcon's build
dir for it (--build-base), then installs
the firmware where colcon's --install-base and --merge-install say (espdock.firmware.colcon_install),
with the output in colcon's log and event handlers. Its test task runs the host tests a firmware
package declares (`colcon test` neither fails nor warns on one). Only colcon imports this
module; espdock never does, so it costs espdock nothing.
"""

from __future__ import annotations

import asyncio
import sys
from pathlib import Path

from colcon_core.event.output import StderrLine, StdoutLine
from colcon_core.event.test import TestFailure
from colcon_core.package_identification import IgnoreLocationException, PackageIdentificationExtensionPoint
from colcon_core.plugin_system import satisfies_version
from colcon_core.task import TaskExtensionPoint, run

PACKAGE_TYPE = "ros.esp_idf"
# The Python espdock runs with: this one, or espdock's own when colcon runs in another Python
# (set by the shim `espdock colcon-extension install` writes).
ESPDOCK_PYTHON = sys.executable
# espdock builds hold the workspace lock: colcon's parallel jobs take turns (one process).
_one_at_a_time = asyncio.Lock()


class EspIdfPackageIdentification(PackageIdentificationExtensionPoint):
    """Identify ESP-IDF firmware packages: a package.xml whose build type is esp_idf."""

    # Before colcon-ros (150) and colcon-cmake (which would take the IDF project's
    # CMakeLists.txt for a plain CMake package).
    PRIORITY = 200

    def __init__(self) -> None:
        super().__init__()
        satisfies_version(PackageIdentificationExtensionPoint.EXTENSION_POINT_VERSION, "^1.0")

    def identify(self, desc) -> None:
        if desc.type is not None or not (desc.path / "package.xml").is_file():
            return
        from espdock.errors import WorkspaceError
        from espdock.workspace import FIRMWARE_BUILD_TYPE, IGNORE_MARKERS, read_package

        if any((desc.path / marker).exists() for marker in IGNORE_MARKERS):
            raise IgnoreLocationException()
        try:
            package = read_package(desc.path / "package.xml")
        except WorkspaceError:
            return  # not ours to judge: colcon-ros reports invalid manifests
        if package.build_type != FIRMWARE_BUILD_TYPE:
            return
        desc.type = PACKAGE_TYPE
        desc.name = desc.name or package.name
        for category in ("build", "run"):
            desc.dependencies[category] |= set(package.depends)


class EspIdfBuildTask(TaskExtensionPoint):
    """Build a firmware package with `espdock build --only firmware PKG`."""

    def __init__(self) -> None:
        super().__init__()
        satisfies_version(TaskExtensionPoint.EXTENSION_POINT_VERSION, "^1.0")

    async def build(self, *, additional_hooks=None) -> int:
        pkg = self.context.pkg
        args = self.context.args
        # espdock's own workspace settings decide the image and the IDF build dir.
        package_dir = str(Path(pkg.path).resolve())
        install = [ESPDOCK_PYTHON, "-m", "espdock.firmware.colcon_install"]
        # colcon's --build-base decides where the IDF build dir is (args.build_base is this
        # package's, BUILD_BASE/PKG), its --install-base and --merge-install where the firmware goes.
        steps = (
            ("build dir", [*install, "--build-dir", package_dir, pkg.name, str(Path(args.build_base).absolute())]),
            ("espdock build", [ESPDOCK_PYTHON, "-m", "espdock", "build", "--only", "firmware", pkg.name]),
            ("install", [*install, package_dir, pkg.name, str(Path(args.install_base).absolute())]
             + (["--merged"] if getattr(args, "merge_install", False) else [])),
        )  # fmt: skip
        async with _one_at_a_time:
            for name, argv in steps:
                self.progress(name)
                completed = await run(self.context, argv, cwd=package_dir)
                if completed.returncode:
                    return completed.returncode
        return 0


class EspIdfTestTask(TaskExtensionPoint):
    """`colcon test` of a firmware package: its host tests (CMake and CTest, JUnit results where
    `colcon test-result` finds them) when it declares them; else nothing to run, and no warning."""

    def __init__(self) -> None:
        super().__init__()
        satisfies_version(TaskExtensionPoint.EXTENSION_POINT_VERSION, "^1.0")

    async def test(self, *, additional_hooks=None) -> int:
        from espdock.errors import EspdockError
        from espdock.ros.testing import HOST_TESTS_TAG, host_test_steps, host_tests_dir, host_tests_failed

        pkg = self.context.pkg
        try:
            source = host_tests_dir(Path(pkg.path).resolve())
        except EspdockError as exc:
            self.context.put_event_into_queue(StderrLine(f"{exc.message}. {exc.hint}\n".encode()))
            return 1
        if source is None:
            self.context.put_event_into_queue(
                StdoutLine(f"{pkg.name}: firmware package without host tests ({HOST_TESTS_TAG}): nothing to run\n")
            )
            return 0
        build = Path(self.context.args.build_base) / "host_tests"
        junit = Path(self.context.args.build_base) / "test_results" / pkg.name / "host_tests.xml"
        junit.parent.mkdir(parents=True, exist_ok=True)
        for argv in host_test_steps(source, build, junit):
            self.progress(argv[0])
            completed = await run(self.context, list(argv), cwd=str(source))
            failed = host_tests_failed(argv, completed.returncode, junit)
            if failed is not None:
                if not failed:
                    self.context.put_event_into_queue(TestFailure(pkg.name))
                return completed.returncode if failed else 0
        return 0
