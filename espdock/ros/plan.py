"""Planning the ROS side: the ROS build image, its runtime images and the colcon build step."""

from __future__ import annotations

import hashlib
import os
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path

from espdock.build.steps import (
    EnsureBaseImage,
    EnsureImage,
    ImageSpec,
    container_path,
    dockerfile_args,
    image_key,
    image_origin,
    keyed_image,
)
from espdock.config import Config
from espdock.errors import WorkspaceError
from espdock.images.bootstrap import debootstrap_suite
from espdock.layout import (
    ROS_BUILD_BASE,
    ROS_DOCKERFILE,
    ROS_OFFICIAL_DOCKERFILE,
    ROSDEP_CONTEXT_DIR,
)
from espdock.ros import rosdeps
from espdock.ros.colcon import (
    ColconSettings,
    closure,
    egg_info_order_define,
    left_out,
    not_naming,
    sets_build_testing,
    with_build_testing,
    with_egg_info_order,
)
from espdock.workspace import BuildInputs, Package, PackageKind, Workspace, select_up_to, text_digest


@dataclass(frozen=True)
class ColconBuild:
    """colcon build of PACKAGES (in build order), in a container of IMAGE with the workspace mounted,
    run in its colcon root."""

    image: str
    packages: tuple[str, ...]
    # Each package's directory relative to the colcon root, and its workspace dependencies: what
    # colcon is pointed at, and what the runner's stamps are made of (a no-change build starts
    # no container).
    sources: tuple[tuple[str, str], ...] = ()
    depends: tuple[tuple[str, tuple[str, ...]], ...] = ()
    colcon_root: str = "ws"
    force: bool = False
    name: str = "colcon build"
    # The options given after `--` (checked: espdock.ros.colcon), each package's colcon settings
    # digest, and the user's colcon defaults file on the host (mounted), if any.
    colcon_args: tuple[str, ...] = ()
    settings: tuple[tuple[str, str], ...] = ()
    defaults_file: str | None = None
    # The cmake-args the colcon defaults files set, which the options given here would replace, and
    # whether they turn symlink-install on.
    defaults_cmake_args: tuple[str, ...] = ()
    defaults_symlink_install: bool = False
    # TESTING: a build for `espdock test` (tests configured, in the image with the test
    # dependencies); TESTS_OFF: CMake packages configured with BUILD_TESTING=OFF (the wheels
    # image lacks ament's lint packages), unless the options after `--` set it.
    testing: bool = False
    tests_off: bool = False
    # Every ROS package of the workspace, not a selection (`espdock build PKG`): the options of such
    # a build are the workspace's, which `espdock test` and `run` judge install/ by.
    whole: bool = True
    # The workspace's ROS packages this step leaves out (a selection's others), which colcon is not
    # shown: the options after `--` and the defaults files' name them to colcon no more.
    outside: tuple[str, ...] = ()
    # The packages of a Python build type, which read no BUILD_TESTING (see stamp_images).
    python: tuple[str, ...] = ()
    # Each package's workspace dependencies whose builds its own build reads, where fewer than
    # DEPENDS: a Python package's build (setup.py) reads no exec_depend or test_depend, so an edit of
    # an interface package it only runs with builds that package and its CMake users, not it (see
    # build_reads). What builds on it reads them all: colcon's environment for it holds them.
    reads: tuple[tuple[str, tuple[str, ...]], ...] = ()
    # A test build's: the stamp_images of the plain build its install also serves (tests are
    # built, not installed), so `espdock build` after `espdock test` rebuilds nothing.
    serves: tuple[tuple[str, str], ...] = ()
    # The PACKAGES this step builds, when not all: the others are dependencies a step before it
    # built, which colcon finds (and sources) in install/ as it finds any up-to-date package.
    selected: tuple[str, ...] = ()
    # The ROS image's kind (its build image's repository: flavour and distro), whose paths the
    # packages' CMake caches hold; a test image over it is the same.
    underlay: str = ""
    # Each package's package.xml dependencies, and which of them are test_depend only: what a
    # failure's hint says about a dependency colcon could not find.
    declared: tuple[tuple[str, frozenset[str], frozenset[str]], ...] = ()
    # The interface packages among PACKAGES (see stale_interfaces).
    interfaces: tuple[str, ...] = ()

    def stale_interfaces(self, rebuild: tuple[str, ...]) -> tuple[str, ...]:
        """The interface packages in REBUILD that depend on another one in it: their build dirs
        must go. rosidl's type description step depends on no file of the packages it refers
        to (jazzy's rosidl_generator_type_description leaves its _dependency_files empty), so an
        incremental build keeps their old type hashes and names; the node then aborts on a hash
        assertion, or fails to import an undefined symbol, with every build saying it built."""
        changed = set(rebuild) & set(self.interfaces)
        return tuple(n for n, deps in self.depends if n in changed and changed & set(deps))

    def build_reads(self, name: str) -> set[str]:
        """The workspace packages package NAME's build reads: its dependencies (READS' of them, for
        a Python package) and, as colcon's environment for the build holds them, all of theirs."""
        direct = dict(self.reads).get(name, dict(self.depends).get(name, ()))
        return (set(direct) | closure(direct, dict(self.depends))) - {name}

    @property
    def workdir(self) -> str:
        return container_path(self.colcon_root)

    @property
    def building(self) -> tuple[str, ...]:
        """The packages this step builds and stamps."""
        return self.selected or self.packages

    @property
    def options(self) -> tuple[str, ...]:
        """The options after `--`, with BUILD_TESTING=OFF where TESTS_OFF asks for it, and ON for
        a test build (CMake would keep the OFF an earlier build cached)."""
        if self.testing:
            options = with_build_testing(self.colcon_args, "ON", self.defaults_cmake_args, force=True)
        elif self.tests_off:
            options = with_build_testing(self.colcon_args, "OFF", self.defaults_cmake_args)
        else:
            options = self.colcon_args
        return with_egg_info_order(options, egg_info_order_define(self.workdir), self.defaults_cmake_args)

    @property
    def effective_args(self) -> tuple[str, ...]:
        """The options after `--` with the --symlink-install the defaults file gives: what decides
        the kind of install colcon makes (see install_kind_switched)."""
        if self.defaults_symlink_install and "--symlink-install" not in self.colcon_args:
            return (*self.colcon_args, "--symlink-install")
        return self.colcon_args

    @property
    def says_tests_off(self) -> bool:
        """Whether this build turns the CMake packages' tests off itself (the user did not set it)."""
        return self.tests_off and not sets_build_testing((*self.colcon_args, *self.defaults_cmake_args))

    def stamp_images(self) -> dict[str, str]:
        """What each package's stamp holds of the image and how its tests are configured: a test
        build and a plain one have different stamps (a plain build takes a test build's install:
        serves). A Python package's, the image alone: whether this build's CMake packages have
        their tests (none may be among them) changes nothing it builds."""
        configured = "tests" if self.testing else "no-tests" if self.says_tests_off else ""
        cmake = f"{self.image}\0{configured}" if configured else self.image
        # An interface package built before its egg-info was ordered (EGG_INFO_ORDER) may list its
        # generated modules or not: an upgraded espdock builds it (and what depends on it) once more.
        ordered = f"{cmake}\0egg-info-ordered"
        return {
            name: self.image if name in self.python else ordered if name in self.interfaces else cmake
            for name in self.packages
        }

    def argv(self, rebuild: tuple[str, ...] = ()) -> tuple[str, ...]:
        """colcon's command line; REBUILD: only these packages (the changed ones and their
        dependents), the others being up to date in install/, where colcon finds them."""
        # Exactly these packages: colcon never sees the firmware packages (a build type it has
        # no task for) nor, for a selection, the packages left out.
        select = ("--packages-select", *rebuild) if rebuild and len(rebuild) < len(self.packages) else ()
        return (
            "colcon", "build", "--base-paths", *(rel for _, rel in self.sources), "--build-base", ROS_BUILD_BASE,
            # Live output per line plus colcon's own start/finish lines.
            "--event-handlers", "console_direct+", "console_start_end+", "summary+",
            *select, *not_naming(self.options, self.outside, self.packages),
        )  # fmt: skip


@dataclass(frozen=True)
class RuntimeImage:
    """The workspace's runtime image: BASE (no compilers) plus the install trees of PACKAGES, tagged
    REPOSITORY:<key> (the key hashes BASE's key and every installed file) and REPOSITORY:latest."""

    base: ImageSpec
    repository: str
    packages: tuple[str, ...]
    colcon_root: str = "ws"
    name: str = "runtime image"

    @property
    def stable_tag(self) -> str:
        return f"{self.repository}:latest"


# Where a runtime image holds the workspace's install tree (the entrypoint sources it).
RUNTIME_INSTALL = "/opt/espdock/ws/install"


# What Dockerfile.ros-official's runtime stage adds from docker/.
OFFICIAL_ENTRYPOINT = "docker/ros-entrypoint.sh"


# The stage of the ROS image's Dockerfile that runtime images start from.
RUNTIME_STAGE = "runtime"


def base_image(config: Config, ros_dockerfile_text: str) -> str:
    """The image a ROS Dockerfile starts FROM: the configured one, else its BASE_IMAGE default."""
    return config.base_image or dockerfile_args(ros_dockerfile_text).get("BASE_IMAGE", "")


def ros_build_image(
    config: Config,
    dockerfile_text: str,
    image_files: Mapping[str, bytes],
    own_files: frozenset[str] = frozenset(),
    rosdep_lock: dict | None = None,
    dockerfile: str = ROS_DOCKERFILE,
) -> ImageSpec:
    """The image colcon runs in: DOCKERFILE's `build` stage, keyed by its inputs, built from a
    context of just those (docker/ for the wheels, and what the rosdep lock installs)."""
    base = base_image(config, dockerfile_text)
    files = {
        dockerfile: dockerfile_text.encode(),
        **image_files,
        **{f"{ROSDEP_CONTEXT_DIR}/{n}": data for n, data in rosdeps.image_files(rosdep_lock).items()},
    }
    flavour = "" if dockerfile == ROS_DOCKERFILE else "-official"
    repository = f"espdock/ros-{config.ros_distro}{flavour}-build"
    spec = keyed_image(repository, dockerfile, "build", (("BASE_IMAGE", base),), files, context=files)
    return replace(spec, origin=image_origin(dockerfile, files, own_files))


def ros_image(config: Config, inputs: BuildInputs) -> tuple[str, str, rosdeps.RosImage]:
    """The chosen ROS image (setting ros_image): its Dockerfile's name and text, and what it provides."""
    if config.ros_image == "official":
        text = inputs.ros_official_dockerfile
        # The official image's ament index is not known before it is pulled: every dependency
        # goes through rosdep, whose ROS package rules (ros-<distro>-*) apt finds installed.
        # Its apt's Python packages constrain the lock's pip part: another image, another lock.
        constraints = (("BASE_IMAGE", base_image(config, text)),)
        image = rosdeps.RosImage("official", config.ros_distro, _rosdep_os(text), frozenset(), constraints)
        return ROS_OFFICIAL_DOCKERFILE, text, image
    text = inputs.ros_dockerfile
    locks = {rel: d for rel, d in sorted(inputs.ros_files.items()) if re.fullmatch(r"docker/ros-[a-z]+\.txt", rel)}
    provided = rosdeps.wheel_packages((data.decode(errors="replace") for data in locks.values()), config.ros_distro)
    constraints = tuple((rel, text_digest(data)) for rel, data in locks.items())
    return ROS_DOCKERFILE, text, rosdeps.RosImage("wheels", config.ros_distro, _rosdep_os(text), provided, constraints)


def _rosdep_os(dockerfile_text: str) -> str:
    os_spec = dockerfile_args(dockerfile_text).get("ROSDEP_OS", "")
    if not re.fullmatch(r"[a-z]+:[a-z0-9.]+", os_spec):
        raise WorkspaceError(
            f"the ROS image's Dockerfile declares no ARG ROSDEP_OS=<os>:<version> (got {os_spec!r})",
            "It names the OS rosdep resolves the packages' dependencies for, e.g. ARG ROSDEP_OS=debian:bookworm.",
        )
    return os_spec


def has_stage(dockerfile: bytes, stage: str) -> bool:
    """Whether DOCKERFILE declares a build stage named STAGE (`FROM ... AS STAGE`)."""
    pattern = rb"(?im)^\s*FROM\s+(--\S+\s+)*\S+\s+AS\s+" + re.escape(stage.encode()) + rb"\s*$"
    return re.search(pattern, dockerfile) is not None


def runtime_base_image(build: ImageSpec) -> ImageSpec:
    """The runtime base that goes with the ROS build image BUILD: the `runtime` stage of the same
    Dockerfile, from the same inputs. Whichever ROS image the build uses (its Dockerfile is chosen
    in one place), its runtime images start from this stage of it."""
    files = dict(build.context or ())
    spec = keyed_image(
        build.repository.removesuffix("-build") + "-runtime",
        build.dockerfile,
        RUNTIME_STAGE,
        build.build_args,
        files,
        context=files,
        extra={"target": RUNTIME_STAGE.encode()},
    )
    return replace(spec, origin=build.origin)


# The longest name a directory's gives (the `name` setting may be longer, to Docker's limit).
LONGEST_NAME = 100


def runtime_repository(config: Config, workspace: Workspace) -> str:
    """espdock/<name>: the workspace's runtime images (name: the setting, else the directory's name)."""
    if config.name:
        return f"espdock/{config.name}"
    name = _image_component(workspace.root.name)
    # Of the directory's name, not its path: a clone or a moved workspace keeps its image name
    # (the compose file `init` writes names it).
    digest = hashlib.sha256(workspace.root.name.encode()).hexdigest()[:8]
    if not name:
        # A name of no ASCII letter or digit (ロボット, _-..): one of its own, not one every such
        # workspace would share (each build's :latest replacing the other's).
        name = f"workspace-{digest}"
    elif len(name) > LONGEST_NAME:
        # Docker refuses a repository's name over 255 characters (an engine's HTTP 400, after the build).
        name = f"{name[: LONGEST_NAME - 9].rstrip('._-')}-{digest}"
    return f"espdock/{name}"


def _image_component(text: str) -> str:
    """TEXT (a directory's name) as a path component of an image reference: Docker's grammar takes
    one separator (., _, __ or dashes) between letters and digits, and `robot_ (copy)` made
    `robot_-copy`, which every run refused as an "invalid reference format"."""
    name = re.sub(r"[^a-z0-9._-]+", "-", text.lower())
    name = re.sub(
        r"[._-]{2,}", lambda run: run.group() if run.group() == "__" or set(run.group()) == {"-"} else "-", name
    )
    return name.strip("._-")


def runtime_image_spec(step: RuntimeImage, install_digest: str) -> ImageSpec:
    """The runtime image of STEP for an install tree with INSTALL_DIGEST: one layer over the base."""
    dockerfile = f"FROM {step.base.tag} AS workspace\nCOPY install {RUNTIME_INSTALL}\n"
    key, inputs = image_key({"base": step.base.key.encode(), "install": install_digest.encode()})
    return ImageSpec(
        repository=step.repository,
        key=key,
        dockerfile="Dockerfile",
        target="workspace",
        build_args=(),
        inputs=inputs,
        context=(("Dockerfile", dockerfile.encode()),),
        origin=f"generated: {step.base.tag} plus the install trees of {', '.join(step.packages)}",
    )


def checked_packages(
    packages: tuple[Package, ...],
    selected: tuple[Package, ...],
    colcon_args: tuple[str, ...] = (),
    checked: tuple[str, ...] | None = None,
) -> tuple[Package, ...]:
    """The packages whose dependencies the image must serve: what colcon builds of SELECTED (its
    --packages-skip and --packages-ignore options honoured), or, for `run` and `shell`, CHECKED
    and the workspace packages they depend on (none for a shell)."""
    if checked is not None:
        return select_up_to(packages, checked) if checked else ()
    depends = {p.name: p.depends for p in packages}
    skipped = left_out(colcon_args, depends)
    return tuple(p for p in selected if p.name not in skipped)


# colcon's Python build types: no CMake, no BUILD_TESTING.
PYTHON_BUILD_TYPES = frozenset({"ament_python", "python"})


def ros_steps(
    workspace: Workspace,
    config: Config,
    ros: tuple[Package, ...],
    ros_image: ImageSpec,
    all_packages: tuple[Package, ...],
    force: bool = False,
    colcon: ColconSettings | None = None,
    testing: bool = False,
    tests_off: bool = False,
) -> list[EnsureBaseImage | EnsureImage | ColconBuild | RuntimeImage]:
    """The ROS side of a build of ROS (packages in build order): the ROS image and its base, the
    colcon build and, when the setting asks for it, the runtime image (see build.plan.plan_build)."""
    colcon = colcon or ColconSettings()
    names = {p.name for p in ros}
    every_ros = {p.name for p in all_packages if p.kind is PackageKind.ROS}
    base = dict(ros_image.build_args)["BASE_IMAGE"]
    steps: list[EnsureBaseImage | EnsureImage | ColconBuild | RuntimeImage] = [
        EnsureBaseImage(base, debootstrap=debootstrap_suite(base, config) is not None),
        EnsureImage(ros_image),
        ColconBuild(
            image=ros_image.tag,
            packages=tuple(p.name for p in ros),
            sources=tuple((p.name, Path(os.path.relpath(p.path, workspace.ws_dir)).as_posix()) for p in ros),
            depends=tuple((p.name, tuple(sorted(p.depends & names))) for p in ros),
            colcon_root=workspace.colcon_root,
            force=force,
            colcon_args=colcon.args,
            settings=tuple(item for item in colcon.digests if item[0] in names),
            defaults_file=colcon.defaults_file,
            defaults_cmake_args=colcon.cmake_args,
            defaults_symlink_install=colcon.symlink_install,
            testing=testing,
            # Only CMake packages read BUILD_TESTING: a workspace of Python packages is told nothing.
            tests_off=tests_off and not testing and any(p.build_type not in PYTHON_BUILD_TYPES for p in ros),
            python=tuple(p.name for p in ros if p.build_type in PYTHON_BUILD_TYPES),
            reads=tuple(
                (p.name, tuple(sorted(p.build_depends & names)))
                for p in ros
                if p.build_type in PYTHON_BUILD_TYPES
                and p.build_depends is not None
                and (p.depends - p.build_depends) & names  # a workspace package it only runs or tests with
            ),
            declared=tuple((p.name, p.depends, p.test_only_depends) for p in ros),
            underlay=ros_image.repository,
            interfaces=tuple(p.name for p in ros if p.is_interface),
            whole=names == every_ros,
            outside=tuple(sorted(every_ros - names)),
        ),
    ]
    # Only when asked (setting runtime_image): `espdock run` and `espdock compose` make it
    # when they need it, so an edit-build loop does not pay for it.
    if config.runtime_image and (runtime := runtime_step(workspace, config, ros_image, all_packages)):
        steps += [EnsureImage(runtime.base), runtime]
    return steps


def runtime_step(
    workspace: Workspace, config: Config, ros_image: ImageSpec, packages: Iterable[Package]
) -> RuntimeImage | None:
    """The runtime image of the ROS PACKAGES built in ROS_IMAGE; None where the workspace's own
    ROS Dockerfile has no runtime stage (it builds, but makes no runtime image)."""
    dockerfile = dict(ros_image.context or ()).get(ros_image.dockerfile, b"")
    if not has_stage(dockerfile, RUNTIME_STAGE):
        return None
    built = sorted(p.name for p in packages if p.kind is PackageKind.ROS)
    return RuntimeImage(
        runtime_base_image(ros_image), runtime_repository(config, workspace), tuple(built), workspace.colcon_root
    )
