from dataclasses import replace
from pathlib import Path

from espdock.build.plan import plan_build
from espdock.build.steps import EnsureBaseImage, EnsureImage, dockerfile_args
from espdock.config import Config
from espdock.firmware.plan import IdfBuild
from espdock.ros.plan import ColconBuild, RuntimeImage, ros_build_image
from espdock.workspace import Package, PackageKind, Workspace

DOCKERFILE = "ARG BASE_IMAGE=debian:bookworm-slim\nFROM ${BASE_IMAGE} AS build\nFROM ${BASE_IMAGE} AS runtime\n"
FILES = {"docker/ros-runtime.txt": b"rclpy==1\n", "docker/ros-entrypoint.sh": b"#!/bin/sh\n"}


def pkg(name: str, kind=PackageKind.ROS, depends=()) -> Package:
    base = Path("/w/ws/src") if kind is PackageKind.ROS else Path("/w/firmware")
    return Package(name, base / name, kind, "ament_cmake", frozenset(depends))


def test_dockerfile_args_reads_defaults():
    text = 'ARG BASE_IMAGE=debian:bookworm-slim\nARG NO_DEFAULT\n  ARG IDF="v5.3.5"\nFROM x\n'
    assert dockerfile_args(text) == {"BASE_IMAGE": "debian:bookworm-slim", "IDF": "v5.3.5"}


def test_image_key_is_stable_and_changes_with_each_input():
    spec = ros_build_image(Config(), DOCKERFILE, FILES)
    assert spec == ros_build_image(Config(), DOCKERFILE, dict(reversed(FILES.items())))
    keys = {
        spec.key,
        ros_build_image(Config(), DOCKERFILE + "RUN true\n", FILES).key,
        ros_build_image(Config(), DOCKERFILE, {**FILES, "docker/ros-runtime.txt": b"rclpy==2\n"}).key,
        ros_build_image(Config(), DOCKERFILE, {**FILES, "docker/extra.xml": b"<x/>"}).key,
        ros_build_image(Config(base_image="debian:trixie-slim"), DOCKERFILE, FILES).key,
    }
    assert len(keys) == 5


def test_image_tag_carries_the_key_and_base_defaults_to_the_dockerfile():
    spec = ros_build_image(Config(), DOCKERFILE, FILES)
    assert spec.tag == f"espdock/ros-jazzy-build:{spec.key[:16]}"
    assert dict(spec.build_args) == {"BASE_IMAGE": "debian:bookworm-slim"}
    assert spec.target == "build"


def test_build_plan_ensures_images_then_runs_colcon():
    ws = Workspace(Path("/w"))
    spec = ros_build_image(Config(), DOCKERFILE, FILES)
    packages = (pkg("msgs"), pkg("app", depends=["msgs"]))
    plan = plan_build(ws, Config(), packages, spec)
    # The runtime image only when asked: `espdock run` and `espdock compose` ask.
    assert [type(s) for s in plan.steps] == [EnsureBaseImage, EnsureImage, ColconBuild]
    asked = plan_build(ws, Config(runtime_image=True), packages, spec)
    assert [type(s) for s in asked.steps] == [EnsureBaseImage, EnsureImage, ColconBuild, EnsureImage, RuntimeImage]
    colcon = plan.steps[2]
    assert colcon.packages == ("msgs", "app")
    assert colcon.image == spec.tag
    argv = colcon.argv()
    assert argv[argv.index("--base-paths") + 1 : argv.index("--build-base")] == ("src/msgs", "src/app")
    # Its own build base: CMake caches made at the container's paths never meet native ones.
    assert argv[argv.index("--build-base") + 1] == "build/espdock-ros"
    assert colcon.sources == (("msgs", "src/msgs"), ("app", "src/app"))
    assert colcon.workdir == "/workspace/ws"
    assert colcon.depends == (("msgs", ()), ("app", ("msgs",)))
    # Its Debian base, debootstrapped where no registry answers; never the official ROS image.
    assert plan.steps[0].debootstrap
    official = ros_build_image(
        Config(ros_image="official"), DOCKERFILE.replace("debian:bookworm-slim", "ros:jazzy-ros-base"), FILES
    )
    assert not plan_build(ws, Config(ros_image="official"), packages, official).steps[0].debootstrap


def test_a_ros_dockerfile_without_a_runtime_stage_builds_and_makes_no_runtime_image():
    spec = ros_build_image(Config(), "ARG BASE_IMAGE=debian:bookworm-slim\nFROM ${BASE_IMAGE} AS build\n", FILES)
    plan = plan_build(Workspace(Path("/w")), Config(runtime_image=True), (pkg("msgs"),), spec)
    assert [type(s) for s in plan.steps] == [EnsureBaseImage, EnsureImage, ColconBuild]


def test_a_selection_builds_exactly_the_selected_packages_and_their_dependencies():
    spec = ros_build_image(Config(), DOCKERFILE, FILES)
    # What select_up_to gives for `espdock build app`: app and what it depends on.
    plan = plan_build(Workspace(Path("/w")), Config(), (pkg("msgs"), pkg("app", depends=["msgs"])), spec,
                      selected=("app",))  # fmt: skip
    argv = next(s for s in plan.steps if isinstance(s, ColconBuild)).argv()
    assert argv[argv.index("--base-paths") + 1 : argv.index("--build-base")] == ("src/msgs", "src/app")


def test_a_colcon_workspace_layout_builds_in_its_root_and_firmware_anywhere():
    ws = Workspace(Path("/w"), ("src",), ".")
    msgs = Package("msgs", Path("/w/src/msgs"), PackageKind.ROS, "ament_cmake", frozenset())
    cam = Package("cam", Path("/w/src/boards/esp/cam"), PackageKind.FIRMWARE, "esp_idf", frozenset({"msgs"}))
    spec = ros_build_image(Config(), DOCKERFILE, FILES)
    plan = plan_build(ws, Config(), (msgs, cam), spec, idf_images={"cam": spec})
    colcon = next(s for s in plan.steps if isinstance(s, ColconBuild))
    assert colcon.workdir == "/workspace" and colcon.sources == (("msgs", "src/msgs"),)
    build = next(s for s in plan.steps if isinstance(s, IdfBuild))
    assert build.project_dir == "/workspace/src/boards/esp/cam"
    assert build.build_dir == "/workspace/build/cam"
    assert build.install_dir == "/workspace/install/cam/share/cam/firmware"


def test_selecting_a_firmware_package_builds_only_its_ros_dependencies():
    from espdock.workspace import select_up_to

    everything = (pkg("msgs"), pkg("demo", depends=["msgs"]), pkg("cam", PackageKind.FIRMWARE, depends=["msgs"]))
    selected = select_up_to(everything, ["cam"])
    spec = ros_build_image(Config(), DOCKERFILE, FILES)
    plan = plan_build(Workspace(Path("/w")), Config(), selected, spec, selected=("cam",), idf_images={
        "cam": ros_build_image(Config(), DOCKERFILE, FILES)})  # fmt: skip
    colcon = next(s for s in plan.steps if isinstance(s, ColconBuild))
    argv = colcon.argv()
    assert argv[argv.index("--base-paths") + 1 : argv.index("--build-base")] == ("src/msgs",)
    assert "src/demo" not in argv


def test_no_ros_packages_means_no_ros_steps():
    spec = ros_build_image(Config(), DOCKERFILE, FILES)
    assert plan_build(Workspace(Path("/w")), Config(), (), spec).steps == ()


def test_the_runtime_image_is_the_build_images_runtime_stage_plus_every_ros_package_installed():
    spec = ros_build_image(Config(), DOCKERFILE, FILES)
    packages = (pkg("msgs"), pkg("app", depends=["msgs"]), pkg("cam", PackageKind.FIRMWARE))
    config = Config(runtime_image=True)
    plan = plan_build(Workspace(Path("/w/My Robot")), config, packages[:1], spec, all_packages=packages)
    base, runtime = plan.steps[-2:]
    assert isinstance(runtime, RuntimeImage) and base.spec == runtime.base
    assert (base.spec.dockerfile, base.spec.target, base.spec.context) == (spec.dockerfile, "runtime", spec.context)
    assert base.spec.key != spec.key and base.spec.tag.startswith("espdock/ros-jazzy-runtime:")
    # Every ROS package of the workspace, not only the selection; no firmware.
    assert runtime.packages == ("app", "msgs")
    assert runtime.stable_tag == "espdock/my-robot:latest"
    named = plan_build(Workspace(Path("/w/x")), Config(name="bot", runtime_image=True), packages[:1], spec).steps[-1]
    assert named.stable_tag == "espdock/bot:latest"


def test_the_official_ros_image_gives_runtime_images_its_own_runtime_stage():
    root = Path(__file__).resolve().parents[2]
    text = (root / "Dockerfile.ros-official").read_text()
    entrypoint = {"docker/ros-entrypoint.sh": (root / "docker" / "ros-entrypoint.sh").read_bytes()}
    spec = ros_build_image(Config(ros_image="official"), text, entrypoint, dockerfile="Dockerfile.ros-official")
    plan = plan_build(Workspace(Path("/w/bot")), Config(runtime_image=True), (pkg("app"),), spec)
    base, runtime = plan.steps[-2:]
    assert (base.spec.dockerfile, base.spec.target) == ("Dockerfile.ros-official", "runtime")
    assert base.spec.repository == "espdock/ros-jazzy-official-runtime"
    assert "docker/ros-entrypoint.sh" in dict(base.spec.context)
    assert "FROM build AS runtime" in text and '"/ros_entrypoint.sh", "/opt/espdock/entrypoint.sh"' in text
    assert runtime.base == base.spec and runtime.stable_tag == "espdock/bot:latest"


def test_build_testing_is_turned_off_only_where_a_cmake_package_reads_it():
    """A workspace of ament_python packages was told "CMake packages are configured with
    BUILD_TESTING=OFF" at every build."""
    from dataclasses import replace

    ws = Workspace(Path("/w"))
    spec = ros_build_image(Config(), DOCKERFILE, FILES)
    python = tuple(replace(pkg(name), build_type="ament_python") for name in ("talker", "listener"))
    built = plan_build(ws, Config(), python, spec, tests_off=True).steps[2]
    assert not built.says_tests_off and "-DBUILD_TESTING=OFF" not in built.argv()
    mixed = plan_build(ws, Config(), (*python, pkg("msgs")), spec, tests_off=True).steps[2]
    assert mixed.says_tests_off and "-DBUILD_TESTING=OFF" in mixed.argv()


def test_a_python_package_s_stamp_is_the_same_whatever_cmake_packages_build_beside_it():
    """`espdock build talker`, then `espdock build`: the second rebuilt talker, and what depends
    on it, since the first had no CMake package to turn tests off for and stamped it so (as did
    a COLCON_IGNORE put in the workspace's only CMake package, and taken out)."""
    from dataclasses import replace

    ws = Workspace(Path("/w"))
    spec = ros_build_image(Config(), DOCKERFILE, FILES)
    talker = replace(pkg("talker"), build_type="ament_python")
    everything = (pkg("msgs"), talker)
    alone = plan_build(ws, Config(), (talker,), spec, ("talker",), all_packages=everything, tests_off=True).steps[2]
    whole = plan_build(ws, Config(), everything, spec, all_packages=everything, tests_off=True).steps[2]
    assert alone.stamp_images()["talker"] == whole.stamp_images()["talker"]
    assert whole.stamp_images()["msgs"] != whole.stamp_images()["talker"], "msgs is built without its tests"
    assert not alone.says_tests_off, "a build of Python packages alone is told nothing of CMake's tests"


def test_a_firmware_build_failing_on_a_header_of_an_interface_package_it_does_not_depend_on_says_so(tmp_path):
    """The ROS habit (find_package, no <depend>): the micro-ROS library holds only the interfaces
    the package depends on, and the build said "No such file or directory" and "Fix the firmware"."""
    import subprocess

    from espdock.firmware.steps import missing_includes, undeclared_interface_hint

    walk = Package("walk_msgs", Path("/w/ws/src/walk_msgs"), PackageKind.ROS, "ament_cmake", frozenset(), True)
    used = Package("used_msgs", Path("/w/ws/src/used_msgs"), PackageKind.ROS, "ament_cmake", frozenset(), True)
    led = Package("led", Path("/w/firmware/led"), PackageKind.FIRMWARE, "esp_idf", frozenset({"used_msgs"}))
    spec = ros_build_image(Config(), DOCKERFILE, FILES)
    plan = plan_build(Workspace(Path("/w")), Config(), (walk, used, led), spec, idf_images={"led": spec})
    build = next(s for s in plan.steps if isinstance(s, IdfBuild))
    assert build.unreached == ("walk_msgs",)
    # What the compiler says of it (the host's gcc, as the IDF toolchain's).
    source = tmp_path / "main.c"
    source.write_text("#include <walk_msgs/msg/reading.h>\n#include <used_msgs/msg/other.h>\n")
    said = subprocess.run(["gcc", "-c", str(source), "-o", "/dev/null"], capture_output=True, text=True, check=False)
    missing = [header for line in said.stderr.splitlines() for _, header in missing_includes(line)]
    assert missing == ["walk_msgs/msg/reading.h"], said.stderr  # gcc stops at the first
    hint = undeclared_interface_hint(build, missing)
    assert hint is not None and "add <depend>walk_msgs</depend> to firmware/led/package.xml" in hint, hint
    assert undeclared_interface_hint(build, ["used_msgs/msg/other.h", "esp_log.h"]) is None
    # A <test_depend> puts no interface in the library (the firmware's tests run on the host).
    tested = replace(led, depends=led.depends | {"walk_msgs"}, test_only_depends=frozenset({"walk_msgs"}))
    plan = plan_build(Workspace(Path("/w")), Config(), (walk, used, tested), spec, idf_images={"led": spec})
    assert next(s for s in plan.steps if isinstance(s, IdfBuild)).unreached == ("walk_msgs",)
