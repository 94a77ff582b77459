"""The micro-ROS image key and the firmware part of the plan, without an engine."""

import json
import os
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from espdock.build.plan import plan_build, plan_workspace
from espdock.build.steps import EnsureImage
from espdock.config import Config
from espdock.errors import WorkspaceError
from espdock.firmware.plan import (
    IdfBuild,
    InstallFirmware,
    derive_interface_packages,
    images_to_rebuild,
    library_sdkconfig,
    micro_ros_image,
    micro_ros_images,
    package_target,
)
from espdock.ros.plan import ros_build_image
from espdock.workspace import BuildInputs, Package, PackageKind, Workspace

ROOT = Path("/w")


def ros(name, depends=(), interface=False):
    return Package(name, ROOT / "ws/src" / name, PackageKind.ROS, "ament_cmake", frozenset(depends), interface)


def firmware(name, depends=()):
    return Package(name, ROOT / "firmware" / name, PackageKind.FIRMWARE, "esp_idf", frozenset(depends))


META = json.dumps({"names": {"rmw_microxrcedds": {"cmake-args": ["-DRMW_UXRCE_MAX_PUBLISHERS=1"]}}})
PACKAGES = (
    ros("base_msgs", interface=True),
    ros("cam_msgs", depends=["base_msgs", "std_msgs"], interface=True),
    ros("unused_msgs", interface=True),
    ros("nodes", depends=["cam_msgs", "rclpy"]),
    firmware("cam", depends=["cam_msgs", "sensor_msgs"]),
    firmware("led", depends=["std_msgs"]),
)
INPUTS = BuildInputs(
    ros_dockerfile="ARG BASE_IMAGE=debian:bookworm-slim\nARG ROSDEP_OS=debian:bookworm\nFROM ${BASE_IMAGE} AS build\n",
    # The wheels image's lock: what it provides (std_msgs, rclpy) is not a rosdep key.
    ros_files={"docker/ros-runtime.txt": (Path(__file__).parents[2] / "docker/ros-runtime.txt").read_bytes()},
    idf_dockerfile=(
        "ARG IDF_IMAGE=espressif/idf:v5.3.5\nFROM ${IDF_IMAGE} AS idf\nARG MICRO_ROS_REPO=https://x/y\n"
        "ARG MICRO_ROS_COMMIT=abc123\n"
    ),
    idf_files={
        "uros_builder/CMakeLists.txt": b"project(uros_builder)\n",
        "micro_ros_sources.txt": b"https://github.com/ros2/rcl jazzy " + b"a" * 40 + b"\n",
    },
    package_files={
        "base_msgs": {"package.xml": b"<package/>", "msg/Base.msg": b"int32 a\n"},
        "cam_msgs": {"package.xml": b"<package/>", "msg/Cam.msg": b"uint8 framesize\n"},
        "unused_msgs": {"package.xml": b"<package/>", "msg/Unused.msg": b"bool b\n"},
    },
    app_metas={"cam": META},
    sdkconfig_defaults={
        "cam": {"sdkconfig.defaults": b'CONFIG_SPIRAM=y\nCONFIG_FREERTOS_HZ=1000\nCONFIG_ESPDOCK_NODE_NAME="cam"\n'},
    },
)
CAM = PACKAGES[4]


DEFAULT = Config()


def key(config=DEFAULT, inputs=INPUTS, packages=PACKAGES):
    return micro_ros_image(config, inputs, packages, CAM, config.target).key


def test_interfaces_are_derived_transitively_from_firmware_dependencies():
    assert [p.name for p in derive_interface_packages(PACKAGES)] == ["base_msgs", "cam_msgs"]


def test_standard_and_non_interface_dependencies_are_not_extra_packages():
    packages = (ros("nodes", interface=False), firmware("fw", depends=["nodes", "std_msgs"]))
    assert derive_interface_packages(packages) == ()


def test_an_interface_package_outside_the_group_is_named_not_left_out():
    """Without <member_of_group>rosidl_interface_packages</member_of_group> (ros2 pkg create does
    not write it), its messages were left out of the library, and the firmware's build failed on a
    missing header with the hint to fix the firmware."""
    packages = (ros("cam_msgs", depends=["rosidl_default_generators"]), firmware("fw", depends=["cam_msgs"]))
    with pytest.raises(WorkspaceError, match="cam_msgs generates interfaces") as raised:
        derive_interface_packages(packages)
    assert "<member_of_group>rosidl_interface_packages</member_of_group>" in raised.value.hint


def test_a_workspace_package_with_a_standard_interface_s_name_is_refused_for_firmware():
    """A std_msgs of the workspace's own (an overlay adding a message): micro-ROS's library build
    failed on "duplicate package name 'std_msgs'" with the hint to read its output."""
    packages = (ros("std_msgs", interface=True), firmware("fw", depends=["std_msgs"]))
    with pytest.raises(WorkspaceError, match="a package named std_msgs, which micro-ROS builds itself"):
        derive_interface_packages(packages)
    assert derive_interface_packages((ros("std_msgs", interface=True), firmware("fw", depends=["sensor_msgs"]))) == ()


def test_a_test_only_dependency_is_not_in_the_library():
    """A <test_depend> of the firmware or of an interface package it uses went into the library
    (a bigger one, rebuilt when that package changed, failing the firmware over types it never uses)."""
    packages = (
        ros("probe_msgs", interface=True),
        ros("test_msgs_pkg", interface=True),
        replace(ros("robo_msgs", depends=["probe_msgs", "test_msgs_pkg"], interface=True),
                test_only_depends=frozenset({"test_msgs_pkg"})),
        replace(firmware("fw", depends=["robo_msgs", "probe_msgs"]), test_only_depends=frozenset({"probe_msgs"})),
    )  # fmt: skip
    assert [p.name for p in derive_interface_packages(packages)] == ["probe_msgs", "robo_msgs"]


def test_each_firmware_gets_only_its_own_interfaces():
    assert [p.name for p in derive_interface_packages(PACKAGES, CAM)] == ["base_msgs", "cam_msgs"]
    assert derive_interface_packages(PACKAGES, PACKAGES[5]) == ()


def test_key_does_not_depend_on_the_order_inputs_were_read_in():
    shuffled = replace(INPUTS, package_files=dict(reversed(INPUTS.package_files.items())))
    assert key(inputs=shuffled) == key()


@pytest.mark.parametrize(
    "change",
    [
        lambda c, i: (replace(c, idf_image="espressif/idf:v5.4.4"), i),
        lambda c, i: (replace(c, micro_ros_commit="def456"), i),
        lambda c, i: (replace(c, target="esp32s3"), i),
        lambda c, i: (c, replace(i, idf_dockerfile=i.idf_dockerfile + "RUN true\n")),
        lambda c, i: (c, replace(i, idf_files={**i.idf_files, "uros_builder/main/main.c": b"x"})),
        lambda c, i: (c, replace(i, idf_files={**i.idf_files, "micro_ros_sources.txt": b"https://x jazzy -\n"})),
        lambda c, i: (c, replace(i, app_metas={"cam": META.replace("=1", "=2")})),
        lambda c, i: (c, replace(i, sdkconfig_defaults={"cam": {"sdkconfig.defaults": b"CONFIG_FREERTOS_HZ=100"}})),
        lambda c, i: (c, replace(i, sdkconfig_defaults={"cam": {"sdkconfig.defaults": b"# CONFIG_SPIRAM is not set"}})),
        lambda c, i: (
            c,
            replace(
                i,
                package_files={
                    **i.package_files,
                    "cam_msgs": {"package.xml": b"<package/>", "msg/Cam.msg": b"uint16 framesize\n"},
                },
            ),
        ),
        lambda c, i: (
            c,
            replace(
                i,
                package_files={
                    **i.package_files,
                    "base_msgs": {**i.package_files["base_msgs"], "msg/New.msg": b"bool x\n"},
                },
            ),
        ),
    ],
    ids=[
        "idf-image",
        "micro-ros-commit",
        "target",
        "dockerfile",
        "idf-inputs",
        "pins",
        "colcon-meta",
        "freertos-hz",
        "no-psram",
        "msg-edit",
        "dependency-msg-added",
    ],
)
def test_key_changes_with_each_input(change):
    config, inputs = change(Config(), INPUTS)
    assert key(config, inputs) != key()


def test_key_ignores_what_does_not_go_into_the_library():
    # A firmware source change, a ROS node change or an interface no firmware uses: same library.
    unused = replace(INPUTS, package_files={**INPUTS.package_files, "unused_msgs": {"msg/Unused.msg": b"int8 z\n"}})
    assert key(inputs=unused) == key()
    assert key(inputs=replace(INPUTS, ros_files={"docker/ros-runtime.txt": b"rclpy==2"})) == key()
    # The app's own options do not reach the library.
    app_only = {
        "cam": {
            "sdkconfig.defaults": INPUTS.sdkconfig_defaults["cam"]["sdkconfig.defaults"]
            + b"CONFIG_ESPDOCK_CAM_FPS=15\n"
        }
    }
    assert key(inputs=replace(INPUTS, sdkconfig_defaults=app_only)) == key()


def test_image_tag_names_distro_and_target_and_carries_the_key():
    spec = micro_ros_image(Config(), INPUTS, PACKAGES, CAM, "esp32c3")
    assert spec.tag == f"espdock/idf-micro-ros-jazzy-esp32c3:{spec.key[:16]}"
    assert spec.labels()["io.espdock.key"] == spec.key
    assert dict(spec.build_args) == {
        "IDF_IMAGE": "espressif/idf:v5.3.5",
        "IDF_TARGET": "esp32c3",
        "MICRO_ROS_COMMIT": "abc123",
        "MICRO_ROS_REPO": "https://x/y",
    }


def test_context_holds_the_app_s_interfaces_meta_and_library_settings():
    context = dict(micro_ros_image(Config(), INPUTS, PACKAGES, CAM, "esp32").context)
    packages = {
        name.split("/")[2] for name in context if name.startswith("micro-ros/extra_packages/") and name.count("/") > 2
    }
    assert packages == {"base_msgs", "cam_msgs"}
    assert json.loads(context["micro-ros/app-colcon.meta"]) == json.loads(META)
    assert context["micro-ros/sdkconfig.defaults"] == (
        b"CONFIG_FREERTOS_HZ=1000\nCONFIG_MICRO_ROS_ESP_NETIF_WLAN=y\nCONFIG_MICRO_ROS_ESP_XRCE_DDS_MIDDLEWARE=y\n"
        b"CONFIG_SPIRAM=y\n"
    )
    assert "Dockerfile.idf" in context and "docker/idf/uros_builder/CMakeLists.txt" in context


def test_library_settings_take_the_target_file_last_and_only_relevant_keys():
    defaults = {
        "sdkconfig.defaults": (
            b"CONFIG_FREERTOS_HZ=100\nCONFIG_MICRO_ROS_ESP_NETIF_WLAN=y\nCONFIG_LOG_DEFAULT_LEVEL=3\n"
            # The agent's address is the app's: another builds the same library.
            b'CONFIG_MICRO_ROS_AGENT_IP="192.168.1.50"\nCONFIG_MICRO_ROS_AGENT_PORT="8888"\n'
        ),
        "sdkconfig.defaults.esp32s3": b"CONFIG_FREERTOS_HZ=1000\n# CONFIG_MICRO_ROS_ESP_NETIF_WLAN is not set\n",
    }
    assert library_sdkconfig(defaults, "esp32") == (
        "CONFIG_FREERTOS_HZ=100\nCONFIG_MICRO_ROS_ESP_NETIF_WLAN=y\nCONFIG_MICRO_ROS_ESP_XRCE_DDS_MIDDLEWARE=y\n"
    )
    assert library_sdkconfig(defaults, "esp32s3") == (
        "CONFIG_FREERTOS_HZ=1000\n# CONFIG_MICRO_ROS_ESP_NETIF_WLAN is not set\n"
        "CONFIG_MICRO_ROS_ESP_XRCE_DDS_MIDDLEWARE=y\n"
    )


def test_library_settings_are_read_from_the_defaults_files_the_project_names(tmp_path):
    """`set(SDKCONFIG_DEFAULTS "sdkconfig.defaults;sdkconfig.defaults.local")` in the CMakeLists: IDF
    built the app with the local file's CONFIG_FREERTOS_HZ=1000, and libmicroros.a, keyed and built
    from sdkconfig.defaults alone, with 100."""
    from espdock.workspace import Package, PackageKind, Workspace, named_sdkconfig_defaults, read_build_inputs

    project = tmp_path / "src/board"
    project.mkdir(parents=True)
    (project / "sdkconfig.defaults").write_text("CONFIG_FREERTOS_HZ=100\n")
    (project / "sdkconfig.defaults.local").write_text("CONFIG_FREERTOS_HZ=1000\n")
    (project / "sdkconfig.defaults.local.esp32s3").write_text("CONFIG_FREERTOS_HZ=500\n")
    cmake = project / "CMakeLists.txt"
    cmake.write_text(
        "cmake_minimum_required(VERSION 3.16)\n"
        "# set(SDKCONFIG_DEFAULTS ignored.cfg)\n"
        'set(SDKCONFIG_DEFAULTS "${CMAKE_CURRENT_LIST_DIR}/sdkconfig.defaults;sdkconfig.defaults.local")\n'
        "include($ENV{IDF_PATH}/tools/cmake/project.cmake)\nproject(board)\n"
    )
    assert named_sdkconfig_defaults(cmake) == ("sdkconfig.defaults", "sdkconfig.defaults.local")
    board = Package("board", project, PackageKind.FIRMWARE, "esp_idf", frozenset())
    inputs = read_build_inputs(Workspace(tmp_path), [board])
    defaults, order = inputs.sdkconfig_defaults["board"], inputs.sdkconfig_order["board"]
    assert library_sdkconfig(defaults, "esp32", order).startswith("CONFIG_FREERTOS_HZ=1000\n")
    assert library_sdkconfig(defaults, "esp32s3", order).startswith("CONFIG_FREERTOS_HZ=500\n")
    # The chip, from the first of them that names one, as IDF's target guess reads them.
    from espdock.firmware.plan import declared_target

    (project / "sdkconfig.defaults.local").write_text('CONFIG_IDF_TARGET="esp32s3"\nCONFIG_FREERTOS_HZ=1000\n')
    inputs = read_build_inputs(Workspace(tmp_path), [board])
    assert declared_target(inputs.sdkconfig_defaults["board"], inputs.sdkconfig_order["board"]) == "esp32s3"
    assert declared_target(inputs.sdkconfig_defaults["board"]) is None
    # One it cannot tell (a variable of the project's own) leaves IDF's default: sdkconfig.defaults.
    cmake.write_text('set(SDKCONFIG_DEFAULTS "${MY_DEFAULTS}")\nproject(board)\n')
    assert named_sdkconfig_defaults(cmake) == ()


def test_apps_with_different_library_inputs_get_their_own_image_and_equal_ones_share():
    led_meta = META.replace("=1", "=2")
    packages = (*PACKAGES, firmware("led2", depends=["std_msgs"]))
    inputs = replace(INPUTS, app_metas={"cam": META, "led": led_meta, "led2": led_meta})
    specs = micro_ros_images(Config(), inputs, packages)
    assert specs["led"].key == specs["led2"].key != specs["cam"].key
    plan = plan_build(
        Workspace(ROOT), Config(), packages, ros_build_image(Config(), INPUTS.ros_dockerfile, {}), idf_images=specs
    )
    ensured = [s.spec.key for s in plan.steps if isinstance(s, EnsureImage) and s.spec.dockerfile == "Dockerfile.idf"]
    assert sorted(ensured) == sorted({specs["cam"].key, specs["led"].key})
    builds = {s.package: s.image_key for s in plan.steps if isinstance(s, IdfBuild)}
    assert builds == {name: spec.key for name, spec in specs.items()}


def test_micro_ros_rebuild_takes_the_images_of_the_named_packages_each_once():
    led_meta = META.replace("=1", "=2")
    packages = (*PACKAGES, firmware("led2", depends=["std_msgs"]))
    specs = micro_ros_images(
        Config(), replace(INPUTS, app_metas={"cam": META, "led": led_meta, "led2": led_meta}), packages
    )
    names, ws = [p.name for p in packages], Workspace(ROOT)
    assert images_to_rebuild(specs, (), names, ws) == (specs["cam"], specs["led"]), "no name: every image, each once"
    assert images_to_rebuild(specs, ("led", "led2"), names, ws) == (specs["led"],)
    with pytest.raises(WorkspaceError, match="'nodes' is not a firmware package"):
        images_to_rebuild(specs, ("led", "nodes"), names, ws)
    # A misspelt board's name is no package, not a package of another kind.
    with pytest.raises(WorkspaceError, match="no package named 'led_2'") as err:
        images_to_rebuild(specs, ("led_2",), names, ws)
    assert err.value.hint == "Did you mean 'led2'?"


def test_a_malformed_or_missing_pin_file_is_refused_before_any_build():
    bad = replace(INPUTS, idf_files={**INPUTS.idf_files, "micro_ros_sources.txt": b"# ok\nhttps://x jazzy abc\n"})
    with pytest.raises(WorkspaceError) as err:
        key(inputs=bad)
    assert "micro_ros_sources.txt:2:" in err.value.message
    missing = replace(INPUTS, idf_files={"uros_builder/CMakeLists.txt": b""})
    with pytest.raises(WorkspaceError, match=r"micro_ros_sources\.txt is missing"):
        key(inputs=missing)


def test_a_malformed_app_meta_names_the_package():
    bad = replace(INPUTS, app_metas={"cam": "{not json"})
    with pytest.raises(WorkspaceError) as err:
        key(inputs=bad)
    assert "cam/app-colcon.meta" in err.value.message


def test_firmware_steps_build_then_install_each_package():
    specs = micro_ros_images(Config(), INPUTS, PACKAGES)
    spec = specs["cam"]
    ros_spec = ros_build_image(Config(), INPUTS.ros_dockerfile, {})
    plan = plan_build(Workspace(ROOT), Config(), PACKAGES, ros_spec, idf_images=specs)
    firmware_steps = [s for s in plan.steps if isinstance(s, IdfBuild | InstallFirmware)]
    assert [(type(s).__name__, s.package) for s in firmware_steps] == [
        ("IdfBuild", "cam"),
        ("InstallFirmware", "cam"),
        ("IdfBuild", "led"),
        ("InstallFirmware", "led"),
    ]
    build = firmware_steps[0]
    assert build.image == spec.tag
    argv = build.argv()
    assert argv[:5] == ("idf.py", "-C", "/workspace/firmware/cam", "-B", "/workspace/ws/build/cam")
    assert argv[-1] == "build"
    assert firmware_steps[1].run_depends == ("cam_msgs",)


def _chips(cam_targets=("esp32", "esp32s3"), led_chip=b'CONFIG_IDF_TARGET="esp32c3"\n'):
    return replace(
        INPUTS,
        sdkconfig_defaults={**INPUTS.sdkconfig_defaults, "led": {"sdkconfig.defaults": led_chip}},
        supported_targets={"cam": cam_targets},
    )


def test_each_firmware_builds_for_its_own_chip_with_its_own_image():
    inputs = _chips()
    plan = plan_workspace(Workspace(ROOT), Config(target="esp32"), PACKAGES, inputs)
    builds = {s.package: s for s in plan.steps if isinstance(s, IdfBuild)}
    assert {name: step.target for name, step in builds.items()} == {"cam": "esp32", "led": "esp32c3"}
    assert builds["led"].image.startswith("espdock/idf-micro-ros-jazzy-esp32c3:")
    assert builds["cam"].image.startswith("espdock/idf-micro-ros-jazzy-esp32:")
    assert {dict(s.build_args)["IDF_TARGET"] for s in plan.idf_images} == {"esp32", "esp32c3"}


def test_target_overrides_the_chip_of_the_selected_packages_only():
    inputs = _chips()
    plan = plan_workspace(Workspace(ROOT), Config(), PACKAGES, inputs, ("cam",), target="esp32s3")
    assert {s.package: s.target for s in plan.steps if isinstance(s, IdfBuild)} == {"cam": "esp32s3"}
    everything = plan_workspace(Workspace(ROOT), Config(), PACKAGES, inputs, target="esp32s3")
    with_led = replace(inputs, supported_targets={})
    both = plan_workspace(Workspace(ROOT), Config(), PACKAGES, with_led, target="esp32s3")
    assert {s.package: s.target for s in both.steps if isinstance(s, IdfBuild)} == {"cam": "esp32s3", "led": "esp32s3"}
    assert {s.package for s in everything.steps if isinstance(s, IdfBuild)} == {"cam", "led"}


def test_a_chip_the_package_does_not_list_is_refused_before_planning_any_step():
    with pytest.raises(WorkspaceError) as err:
        plan_workspace(Workspace(ROOT), Config(), PACKAGES, _chips(), ("cam",), target="esp32c3")
    assert "cam does not support esp32c3: it supports esp32, esp32s3" in err.value.message
    # The package not built is not held to the override.
    plan = plan_workspace(Workspace(ROOT), Config(), PACKAGES, _chips(), ("led",), target="esp32c3")
    assert [s.package for s in plan.steps if isinstance(s, IdfBuild)] == ["led"]


def test_a_package_that_lists_only_misspelt_chips_is_not_told_to_build_for_one():
    """`targets: [esp32x]`: the hint said `--target esp32x`, which espdock then refused."""
    with pytest.raises(WorkspaceError) as err:
        plan_workspace(Workspace(ROOT), Config(), PACKAGES, _chips(cam_targets=("esp32x",)), ("cam",))
    assert "cam does not support esp32: it supports esp32x" in err.value.message
    assert "--target esp32x" not in (err.value.hint or "") and "none is an ESP-IDF chip" in (err.value.hint or "")
    with pytest.raises(WorkspaceError) as err:
        plan_workspace(Workspace(ROOT), Config(), PACKAGES, _chips(cam_targets=("esp32x", "esp32s3")), ("cam",))
    assert "--target esp32s3" in (err.value.hint or "")


@pytest.mark.parametrize("chip", ["esp32c2", "esp32c5", "esp32c6", "esp32h2", "esp32p4"])
def test_risc_v_chips_but_the_c3_are_refused_with_the_longcalls_reason(chip):
    with pytest.raises(WorkspaceError, match="-mlongcalls"):
        package_target(Config(), _chips(), PACKAGES[5], chip)
    assert package_target(Config(), _chips(), PACKAGES[5], "esp32c3") == "esp32c3"


@pytest.mark.parametrize(
    "line", ['CONFIG_IDF_TARGET="esp32c33"', 'CONFIG_IDF_TARGET="esp32-c3"', "CONFIG_IDF_TARGET='esp32c3'"]
)
def test_an_unknown_chip_in_sdkconfig_defaults_names_the_file(line):
    """A misspelt chip with a dash or in single quotes (which IDF does not read either) built the
    firmware for the workspace's chip, esp32, without a word."""
    from espdock.errors import ConfigError

    with pytest.raises(ConfigError, match=r"CONFIG_IDF_TARGET in led/sdkconfig\.defaults"):
        package_target(Config(), _chips(led_chip=f"{line}\n".encode()), PACKAGES[5])


def test_a_chip_in_sdkconfig_defaults_is_read_quoted_as_idf_writes_it_or_bare():
    assert package_target(Config(), _chips(led_chip=b'CONFIG_IDF_TARGET="esp32c3"\n'), PACKAGES[5]) == "esp32c3"
    assert package_target(Config(), _chips(led_chip=b"CONFIG_IDF_TARGET=esp32c3  \n"), PACKAGES[5]) == "esp32c3"
    assert (
        package_target(Config(target="esp32s3"), _chips(led_chip=b'CONFIG_IDF_TARGET=""\n'), PACKAGES[5]) == "esp32s3"
    )


@pytest.mark.parametrize(
    ("meta", "said"),
    [
        ("[]", "cam/app-colcon.meta is a JSON list, not an object: colcon would skip it"),
        ('"names"', "cam/app-colcon.meta is a JSON string, not an object"),
        ('{"name": {"rmw_microxrcedds": {}}}', "cam/app-colcon.meta has 'name', which colcon does not read"),
        ('{"names": {"rmw_microxrcedds": ["-DX=1"]}}', "names.rmw_microxrcedds is a JSON list, not an object of"),
        ('{"names": {"rmw_microxrcedds": {"cmake-args": "-DX=1"}}}', "cmake-args is not a list of strings"),
        ('{"names": ', "cam/app-colcon.meta is not colcon.meta JSON: Expecting value: line 1"),
    ],
)
def test_an_app_colcon_meta_colcon_would_not_take_as_meant_is_refused_saying_how(meta, said):
    """`[]` said "'list' object has no attribute 'get'"; a package entry that is a list, that its
    cmake-args (there were none) were no list; `name` for `names` dropped every setting silently."""
    inputs = replace(INPUTS, app_metas={"cam": meta})
    with pytest.raises(WorkspaceError) as refused:
        key(inputs=inputs)
    assert said in refused.value.message, refused.value.message
    assert "Did you mean 'names'?" == refused.value.hint if "'name'" in said else "cmake-args" in refused.value.hint


@pytest.mark.parametrize("image", ["espressif/idf:v5.1.4", "espressif/idf:release-v5.2", "espressif/idf:v4.4"])
def test_an_idf_image_older_than_5_3_is_refused_before_anything_builds(image):
    with pytest.raises(WorkspaceError) as err:
        key(config=Config(idf_image=image))
    assert f"idf_image {image}" in err.value.message and "5.3 or newer" in err.value.message


@pytest.mark.parametrize("image", ["espressif/idf:v6.0", "espressif/idf:release-v6.1", "espressif/idf:v7.0.1"])
def test_an_idf_image_of_6_or_later_is_refused_saying_why(image):
    with pytest.raises(WorkspaceError) as err:
        key(config=Config(idf_image=image))
    assert f"idf_image {image}" in err.value.message
    assert "up to, not including, 6" in err.value.message and "picolibc" in err.value.message
    assert "v5.3.5" in err.value.hint


@pytest.mark.parametrize(
    "image", ["espressif/idf:v5.3.5", "espressif/idf:v5.4", "espressif/idf:v5.5.5", "espressif/idf@sha256:" + "a" * 64]
)
def test_idf_5_3_up_to_6_or_a_digest_are_accepted(image):
    assert key(config=Config(idf_image=image))


# The library's build tools (colcon, catkin_pkg, lark, empy) exist only in IDF's venv, so CMake's
# FindPython3 must find that venv's interpreter when micro-ROS is built in Dockerfile.idf. The
# real build cannot run here (no espressif/idf image); the recipe and its guard can.
IDF_RECIPE = Path(__file__).resolve().parents[2] / "Dockerfile.idf"


def library_build_run() -> str:
    """The RUN instruction of Dockerfile.idf that builds libmicroros.a, as one line."""
    joined = IDF_RECIPE.read_text().replace("\\\n", " ")
    (run,) = [line for line in joined.splitlines() if line.startswith("RUN") and "reconfigure" in line]
    return run


def test_the_library_build_points_cmake_at_idf_s_venv_python():
    run = library_build_run()
    rest = run.split('. "$IDF_PATH/export.sh"', 1)[1]
    assert "venv=\"$(python -c 'import sys; print(sys.prefix)')\"" in rest, "the venv is not read after export.sh"
    reconfigure = next(part for part in rest.split("&&") if "reconfigure" in part)
    assert 'VIRTUAL_ENV="$venv"' in reconfigure and 'Python3_ROOT_DIR="$venv"' in reconfigure


FIND_PYTHON_PROJECT = (
    "cmake_minimum_required(VERSION 3.16)\nproject(probe NONE)\nfind_package(Python3 REQUIRED COMPONENTS Interpreter)\n"
)


@pytest.fixture(scope="module")
def pythons(tmp_path_factory) -> dict[str, Path]:
    """Two interpreter prefixes: "idf" stands in for IDF's venv, "other" for any Python outside it."""
    if shutil.which("cmake") is None:
        pytest.skip("cmake is not installed: the guard is tested against caches written by a real CMake run")
    root = tmp_path_factory.mktemp("pythons")
    made = {}
    for name in ("idf", "other"):
        subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(root / name)], check=True)
        made[name] = root / name
    return made


def run_guard(tmp_path: Path, venv: Path, caches: dict[str, Path]) -> subprocess.CompletedProcess:
    """Dockerfile.idf's check of the CMake caches, run on caches that a real CMake's FindPython wrote for
    each package of CACHES, pointed at the interpreter under its prefix the way the RUN points it."""
    guard = library_build_run().split("&& stray=", 1)[1].split("&& test -f", 1)[0]
    component = tmp_path / "component"
    source = tmp_path / "probe"
    source.mkdir()
    (source / "CMakeLists.txt").write_text(FIND_PYTHON_PROJECT)
    for package, prefix in caches.items():
        env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "Python3_ROOT_DIR")}
        env |= {"VIRTUAL_ENV": str(prefix), "Python3_ROOT_DIR": str(prefix)}
        build = component / "micro_ros_src" / "build" / package
        subprocess.run(["cmake", "-S", str(source), "-B", str(build)], env=env, check=True, capture_output=True)
    script = "stray=" + guard.replace("/opt/micro_ros_espidf_component", str(component))
    return subprocess.run(["sh", "-c", f"venv={venv}; {script}"], check=False, capture_output=True, text=True)


def test_a_library_built_with_idf_s_venv_python_passes_the_guard(tmp_path, pythons):
    result = run_guard(tmp_path, pythons["idf"], {"rcl": pythons["idf"], "rclc": pythons["idf"]})
    assert result.returncode == 0, result.stderr


def test_a_library_built_with_another_python_fails_the_image_build_naming_it(tmp_path, pythons):
    result = run_guard(tmp_path, pythons["idf"], {"rcl": pythons["idf"], "rclc": pythons["other"]})
    assert result.returncode == 1
    assert "micro-ROS was built with a Python outside IDF's venv" in result.stderr
    # What FindPython writes: the interpreter as an internal cache entry, not Python3_EXECUTABLE:FILEPATH.
    assert f"rclc/CMakeCache.txt:_Python3_EXECUTABLE:INTERNAL={pythons['other']}/bin/python3" in result.stderr
    assert "rcl/CMakeCache.txt" not in result.stderr


def test_a_choice_left_at_its_default_keys_the_library_as_the_line_that_sets_it():
    """`idf.py save-defconfig` after `espdock new`, no setting changed: it wrote sdkconfig.defaults
    without the template's CONFIG_MICRO_ROS_ESP_XRCE_DDS_MIDDLEWARE=y and _NETIF_WLAN=y (each its
    choice's default), and the next build made a new micro-ROS image of the same library."""

    template = (
        b"CONFIG_MICRO_ROS_ESP_XRCE_DDS_MIDDLEWARE=y\nCONFIG_MICRO_ROS_ESP_NETIF_WLAN=y\nCONFIG_FREERTOS_HZ=1000\n"
    )
    saved = b"CONFIG_FREERTOS_HZ=1000\n"
    assert library_sdkconfig({"sdkconfig.defaults": saved}, "esp32") == library_sdkconfig(
        {"sdkconfig.defaults": template}, "esp32"
    )
    # Another choice's line is no default: its library stays its own.
    serial = b"CONFIG_MICRO_ROS_ESP_UART_TRANSPORT=y\nCONFIG_FREERTOS_HZ=1000\n"
    ethernet = b"CONFIG_MICRO_ROS_ESP_NETIF_ENET=y\nCONFIG_FREERTOS_HZ=1000\n"
    keyed = {library_sdkconfig({"sdkconfig.defaults": text}, "esp32") for text in (saved, serial, ethernet)}
    assert len(keyed) == 3
