"""The micro-ROS image key and the firmware part of the plan, without an engine."""

import json
from dataclasses import replace
from pathlib import Path

import pytest

from espdock.config import Config
from espdock.errors import ConfigError
from espdock.plan import (
    IdfBuild,
    InstallFirmware,
    derive_interface_packages,
    merge_colcon_meta,
    micro_ros_image,
    plan_build,
    ros_build_image,
)
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
    ros_dockerfile="ARG BASE_IMAGE=debian:bookworm-slim\nFROM ${BASE_IMAGE} AS build\n",
    ros_files={},
    idf_dockerfile=(
        "ARG IDF_IMAGE=espressif/idf:v5.3.5\nFROM ${IDF_IMAGE} AS idf\nARG MICRO_ROS_REPO=https://x/y\n"
        "ARG MICRO_ROS_COMMIT=abc123\n"
    ),
    idf_files={"uros_builder/CMakeLists.txt": b"project(uros_builder)\n"},
    package_files={
        "base_msgs": {"package.xml": b"<package/>", "msg/Base.msg": b"int32 a\n"},
        "cam_msgs": {"package.xml": b"<package/>", "msg/Cam.msg": b"uint8 framesize\n"},
        "unused_msgs": {"package.xml": b"<package/>", "msg/Unused.msg": b"bool b\n"},
    },
    app_metas={"cam": META},
)


DEFAULT = Config()


def key(config=DEFAULT, inputs=INPUTS, packages=PACKAGES):
    return micro_ros_image(config, inputs, packages).key


def test_interfaces_are_derived_transitively_from_firmware_dependencies():
    assert [p.name for p in derive_interface_packages(PACKAGES)] == ["base_msgs", "cam_msgs"]


def test_standard_and_non_interface_dependencies_are_not_extra_packages():
    packages = (ros("nodes", interface=False), firmware("fw", depends=["nodes", "std_msgs"]))
    assert derive_interface_packages(packages) == ()


def test_key_is_stable_for_the_same_inputs():
    assert key() == key()
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
        lambda c, i: (c, replace(i, app_metas={"cam": META.replace("=1", "=2")})),
        lambda c, i: (
            c,
            replace(i, package_files={**i.package_files, "cam_msgs": {"package.xml": b"<package/>",
                                                                      "msg/Cam.msg": b"uint16 framesize\n"}}),
        ),
        lambda c, i: (
            c,
            replace(i, package_files={**i.package_files, "base_msgs": {**i.package_files["base_msgs"],
                                                                       "msg/New.msg": b"bool x\n"}}),
        ),
    ],
    ids=["idf-image", "micro-ros-commit", "target", "dockerfile", "idf-inputs", "colcon-meta", "msg-edit",
         "dependency-msg-added"],
)
def test_key_changes_with_each_input(change):
    config, inputs = change(Config(), INPUTS)
    assert key(config, inputs) != key()


def test_key_ignores_what_does_not_go_into_the_library():
    # A firmware source change, a ROS node change or an interface no firmware uses: same library.
    unused = replace(INPUTS, package_files={**INPUTS.package_files, "unused_msgs": {"msg/Unused.msg": b"int8 z\n"}})
    assert key(inputs=unused) == key()
    assert key(inputs=replace(INPUTS, ros_files={"docker/ros-runtime.txt": b"rclpy==2"})) == key()


def test_image_tag_names_distro_and_target_and_carries_the_key():
    spec = micro_ros_image(Config(target="esp32c3"), INPUTS, PACKAGES)
    assert spec.tag == f"espdock/idf-micro-ros-jazzy-esp32c3:{spec.key[:16]}"
    assert spec.labels()["io.espdock.key"] == spec.key
    assert dict(spec.build_args) == {
        "IDF_IMAGE": "espressif/idf:v5.3.5",
        "IDF_TARGET": "esp32c3",
        "MICRO_ROS_COMMIT": "abc123",
        "MICRO_ROS_REPO": "https://x/y",
    }


def test_context_holds_only_the_derived_interface_packages_and_the_merged_meta():
    context = dict(micro_ros_image(Config(), INPUTS, PACKAGES).context)
    packages = {name.split("/")[2] for name in context if name.startswith("micro-ros/extra_packages/") and
                name.count("/") > 2}
    assert packages == {"base_msgs", "cam_msgs"}
    assert json.loads(context["micro-ros/app-colcon.meta"]) == json.loads(META)
    assert "Dockerfile.idf" in context and "docker/idf/uros_builder/CMakeLists.txt" in context


def test_metas_merge_taking_the_largest_counts():
    a = {"names": {"rmw_microxrcedds": {"cmake-args": ["-DRMW_UXRCE_MAX_PUBLISHERS=1", "-DRMW_UXRCE_MAX_SERVICES=2",
                                                        "-DRMW_UXRCE_TRANSPORT=udp"]}}}
    b = {"names": {"rmw_microxrcedds": {"cmake-args": ["-DRMW_UXRCE_MAX_PUBLISHERS=3",
                                                        "-DRMW_UXRCE_MAX_SUBSCRIPTIONS=1"]},
                   "microxrcedds_client": {"cmake-args": ["-DUCLIENT_UDP_TRANSPORT_MTU=4096"]}}}
    merged = json.loads(merge_colcon_meta({"a": json.dumps(a), "b": json.dumps(b)}))
    assert sorted(merged["names"]["rmw_microxrcedds"]["cmake-args"]) == [
        "-DRMW_UXRCE_MAX_PUBLISHERS=3", "-DRMW_UXRCE_MAX_SERVICES=2", "-DRMW_UXRCE_MAX_SUBSCRIPTIONS=1",
        "-DRMW_UXRCE_TRANSPORT=udp",
    ]
    assert merged["names"]["microxrcedds_client"]["cmake-args"] == ["-DUCLIENT_UDP_TRANSPORT_MTU=4096"]
    # Order of packages does not matter.
    assert merge_colcon_meta({"b": json.dumps(b), "a": json.dumps(a)}) == merge_colcon_meta(
        {"a": json.dumps(a), "b": json.dumps(b)}
    )


def test_conflicting_non_numeric_settings_name_both_packages():
    a = {"names": {"rmw_microxrcedds": {"cmake-args": ["-DRMW_UXRCE_TRANSPORT=udp"]}}}
    b = {"names": {"rmw_microxrcedds": {"cmake-args": ["-DRMW_UXRCE_TRANSPORT=custom"]}}}
    with pytest.raises(ConfigError) as err:
        merge_colcon_meta({"cam": json.dumps(a), "led": json.dumps(b)})
    assert "cam" in err.value.message and "led" in err.value.message and "RMW_UXRCE_TRANSPORT" in err.value.message


def test_firmware_steps_build_then_install_each_package():
    spec = micro_ros_image(Config(), INPUTS, PACKAGES)
    ros_spec = ros_build_image(Config(), INPUTS.ros_dockerfile, {})
    plan = plan_build(Workspace(ROOT), Config(), PACKAGES, ros_spec, idf_image=spec)
    firmware_steps = [s for s in plan.steps if isinstance(s, IdfBuild | InstallFirmware)]
    assert [(type(s).__name__, s.package) for s in firmware_steps] == [
        ("IdfBuild", "cam"), ("InstallFirmware", "cam"), ("IdfBuild", "led"), ("InstallFirmware", "led"),
    ]
    build = firmware_steps[0]
    assert build.image == spec.tag
    argv = build.argv()
    assert argv[:5] == ("idf.py", "-C", "/workspace/firmware/cam", "-B", "/workspace/ws/build/cam")
    assert argv[-1] == "build"
    assert firmware_steps[1].run_depends == ("cam_msgs",)
