"""The IDF contract double's own fidelity: it must fail where ESP-IDF fails and embed what
ESP-IDF embeds, or the firmware tests that build against it could pass where the real IDF would
not (see tests/idf_contract_double/README.md).

These need the double's image only, not a built workspace: in a module of their own, a pytest
worker runs them while another builds test_firmware's workspace (`--dist loadfile`)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

pytestmark = [pytest.mark.engine, pytest.mark.slow]

USER_UID = 4243


def run_in_double(double, project: Path, *argv: str) -> subprocess.CompletedProcess:
    tag, _ = double
    return subprocess.run(
        ["docker", "run", "--rm", "-u", f"{USER_UID}:{USER_UID}", "-e", "HOME=/tmp",
         "-v", f"{project}:/project", tag, "idf.py", "-C", "/project", "-B", "/tmp/build", *argv],
        capture_output=True, text=True, check=False,
    )  # fmt: skip


def idf_project(where: Path, main: str = 'idf_component_register(SRCS "main.c")\n', name: str = "") -> Path:
    """A minimal ESP-IDF project at WHERE, NAME (default: the directory's), its main/ registered
    by MAIN with a main.c of an empty app_main."""
    (where / "main").mkdir(parents=True)
    (where / "CMakeLists.txt").write_text(
        "cmake_minimum_required(VERSION 3.16)\ninclude($ENV{IDF_PATH}/tools/cmake/project.cmake)\n"
        f"project({name or where.name})\n"
    )
    (where / "main/CMakeLists.txt").write_text(main)
    (where / "main/main.c").write_text("void app_main(void) {}\n")
    return where


def test_the_double_refuses_headers_of_components_a_component_does_not_require(double, tmp_path):
    """IDF compiles a component with the include dirs of what it requires (publicly, transitively);
    the double must fail where IDF would, or it cannot catch glue that misses a requirement."""
    project = idf_project(tmp_path / "probe")
    (project / "components/netif").mkdir(parents=True)
    (project / "components/netif/netif.c").write_text('#include "esp_eth.h"\n#include "driver/gpio.h"\n')
    component = project / "components/netif/CMakeLists.txt"

    def build(requirements: str) -> subprocess.CompletedProcess:
        component.write_text(f'idf_component_register(SRCS "netif.c" {requirements})\n')
        subprocess.run(["chown", "-R", f"{USER_UID}:{USER_UID}", str(tmp_path)], check=True)
        return run_in_double(double, project, "build")

    # esp_eth requires esp_driver_gpio only privately (ESP-IDF v5.3): its header does not reach us.
    missing = build("REQUIRES esp_eth lwip")
    assert missing.returncode == 2, missing.stdout[-2000:]
    assert "driver/gpio.h: No such file or directory" in missing.stderr
    assert build("REQUIRES esp_eth PRIV_REQUIRES esp_driver_gpio").returncode == 0
    assert build("REQUIRES esp_eth PRIV_REQUIRES driver").returncode == 0  # the legacy umbrella exports it
    # Requirements are read before Kconfig (IDF's early expansion): a Kconfig-conditional one never counts.
    component.write_text(
        'set(req "")\nif(CONFIG_IDF_TARGET_ESP32)\n  set(req esp_driver_gpio)\nendif()\n'
        'idf_component_register(SRCS "netif.c" REQUIRES esp_eth ${req})\n'
    )
    subprocess.run(["chown", "-R", f"{USER_UID}:{USER_UID}", str(tmp_path)], check=True)
    conditional = run_in_double(double, project, "build")
    assert conditional.returncode == 2 and "driver/gpio.h: No such file or directory" in conditional.stderr


def test_the_double_links_esp32_camera_s_driver_only_where_upstream_builds_it(double, tmp_path):
    """esp32-camera compiles its driver only for esp32, esp32s2 and esp32s3: on an esp32c3 an app
    calling esp_camera_init fails at the link, so camera_node lists the chips it supports."""
    project = idf_project(tmp_path / "cam")
    (project / "main/idf_component.yml").write_text('dependencies:\n  espressif/esp32-camera: "^2.0.14"\n')
    (project / "main/main.c").write_text(
        "int esp_camera_init(const void *config);\nvoid app_main(void) { esp_camera_init(0); }\n"
    )
    subprocess.run(["chown", "-R", f"{USER_UID}:{USER_UID}", str(tmp_path)], check=True)
    c3 = run_in_double(double, project, "-DIDF_TARGET=esp32c3", "build")
    assert c3.returncode == 2 and "undefined reference to `esp_camera_init'" in c3.stderr, c3.stdout[-2000:]
    # Another target needs a fresh sdkconfig, as IDF itself says (the build directory went with its container).
    (project / "sdkconfig").unlink()
    s3 = run_in_double(double, project, "-DIDF_TARGET=esp32s3", "build")
    assert s3.returncode == 0, s3.stdout[-2000:] + s3.stderr


def test_the_double_stops_a_component_for_a_chip_outside_its_required_idf_targets(double, tmp_path):
    """ESP-IDF's component.cmake (__component_check_target) ends the configure of a component whose
    REQUIRED_IDF_TARGETS leaves out the chip, which camera_node's registration relies on."""
    project = idf_project(
        tmp_path / "cam", 'idf_component_register(SRCS "main.c"\n    REQUIRED_IDF_TARGETS esp32 esp32s3)\n'
    )
    subprocess.run(["chown", "-R", f"{USER_UID}:{USER_UID}", str(tmp_path)], check=True)
    c3 = run_in_double(double, project, "-DIDF_TARGET=esp32c3", "build")
    assert c3.returncode != 0, c3.stdout[-2000:]
    assert "Component main only supports targets: esp32;esp32s3" in c3.stdout + c3.stderr
    (project / "sdkconfig").unlink(missing_ok=True)
    s3 = run_in_double(double, project, "-DIDF_TARGET=esp32s3", "build")
    assert s3.returncode == 0, s3.stdout[-2000:] + s3.stderr


def project(where: Path, reproducible: bool) -> Path:
    idf_project(where, name="probe")  # one name: the app's bytes may differ only by the path and time
    if reproducible:
        (where / "sdkconfig.defaults").write_text("CONFIG_APP_REPRODUCIBLE_BUILD=y\n")
    return where


def build_in_double(tag: str, host_dir: Path, container_dir: str) -> dict[str, bytes]:
    """idf.py build of the project at HOST_DIR, seen in the container at CONTAINER_DIR, as a user
    would run it outside espdock: no SOURCE_DATE_EPOCH, their own paths."""
    result = subprocess.run(
        ["docker", "run", "--rm", "-e", "HOME=/tmp", "-v", f"{host_dir}:{container_dir}", tag,
         "idf.py", "-C", container_dir, "-B", f"{container_dir}/build", "build"],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr
    return {name: (host_dir / "build" / name).read_bytes() for name in ("probe.elf", "probe.bin")}


def test_the_double_embeds_paths_and_build_time_unless_the_option_is_set(double, tmp_path):
    """Without CONFIG_APP_REPRODUCIBLE_BUILD the double's app carries its build time and, in the
    ELF, the absolute source paths; so test_reproducible's clones install identical files because
    the option is set."""
    tag, _ = double
    plain_a = build_in_double(tag, project(tmp_path / "plain-a", False), "/home/alice/probe")
    plain_b = build_in_double(tag, project(tmp_path / "plain-b", False), "/srv/ci/job-7/probe")
    assert plain_a["probe.elf"] != plain_b["probe.elf"]
    assert b"/home/alice/probe/main/main.c" in plain_a["probe.elf"]
    repro_a = build_in_double(tag, project(tmp_path / "repro-a", True), "/home/alice/probe")
    repro_b = build_in_double(tag, project(tmp_path / "repro-b", True), "/srv/ci/job-7/probe")
    assert repro_a == repro_b
    assert b"/home/alice" not in repro_a["probe.elf"] and b"/COMPONENT_MAIN_DIR/main.c" in repro_a["probe.elf"]


def test_the_double_refuses_a_partition_table_gen_esp32part_refuses_and_names_sources_absolutely(double, tmp_path):
    """Two partitions of one name and an app at an offset not 64 KB aligned built and installed
    against the double (the flash line wrote the app at 0x18000), where gen_esp32part.py's verify()
    stops the real build; and gcc names a file as IDF's CMake passes it, by its absolute path."""
    project = idf_project(tmp_path / "parts")
    (project / "sdkconfig.defaults").write_text(
        'CONFIG_PARTITION_TABLE_CUSTOM=y\nCONFIG_PARTITION_TABLE_CUSTOM_FILENAME="partitions.csv"\n'
    )
    table = project / "partitions.csv"

    def build(rows: str) -> subprocess.CompletedProcess:
        table.write_text("# Name, Type, SubType, Offset, Size, Flags\nnvs, data, nvs, 0x9000, 0x6000,\n" + rows)
        (project / "sdkconfig").unlink(missing_ok=True)
        subprocess.run(["chown", "-R", f"{USER_UID}:{USER_UID}", str(tmp_path)], check=True)
        return run_in_double(double, project, "build")

    assert build("factory, app, factory, 0x10000, 0x100000,\n").returncode == 0
    twice = build(
        "storage, data, spiffs, 0xf000, 0x1000,\nfactory, app, factory, 0x10000, 1M,\nstorage, data, fat, , 64K,\n"
    )
    assert twice.returncode == 2 and "Partition names must be unique" in twice.stderr, twice.stderr[-2000:]
    unaligned = build("factory, app, factory, 0x18000, 0x100000,\n")
    assert unaligned.returncode == 2, unaligned.stdout[-2000:]
    assert "Partition factory invalid: Offset 0x18000 is not aligned to 0x10000" in unaligned.stderr

    table.unlink()
    (project / "sdkconfig.defaults").unlink()
    (project / "main/main.c").write_text("#error deliberately broken\nvoid app_main(void) {}\n")
    broken = build("")
    assert broken.returncode == 2 and "/project/main/main.c:1:2: error: #error deliberately broken" in broken.stderr


def test_the_double_reads_the_defaults_files_a_project_sets_sdkconfig_defaults_to(double, tmp_path):
    """IDF v5.3's project.cmake takes the SDKCONFIG_DEFAULTS variable a CMakeLists sets before
    project() over sdkconfig.defaults (each file then its chip's variant). The double read
    sdkconfig.defaults alone, so a library espdock built without the other files' settings agreed
    with the app it built, where the real app would differ."""
    project = idf_project(tmp_path / "local")
    cmake = project / "CMakeLists.txt"
    cmake.write_text('set(SDKCONFIG_DEFAULTS "sdkconfig.defaults;sdkconfig.defaults.local")\n' + cmake.read_text())
    (project / "sdkconfig.defaults").write_text("CONFIG_FREERTOS_HZ=100\n")
    (project / "sdkconfig.defaults.local").write_text("CONFIG_FREERTOS_HZ=1000\n")
    subprocess.run(["chown", "-R", f"{USER_UID}:{USER_UID}", str(tmp_path)], check=True)
    configured = run_in_double(double, project, "reconfigure")
    assert configured.returncode == 0, configured.stdout[-2000:] + configured.stderr
    assert "CONFIG_FREERTOS_HZ=1000\n" in (project / "sdkconfig").read_text()


def test_the_double_names_what_its_configure_read_in_build_ninja_s_rule_to_re_run_cmake(double, tmp_path):
    """CMake's Ninja generator lists every file a configure read (each CMakeLists.txt, each file
    they include(), IDF's CMAKE_CONFIGURE_DEPENDS such as idf_component.yml) as the implicit inputs
    of `build build.ninja: RERUN_CMAKE`, absolute and in Ninja's escapes; espdock reads them there
    for a firmware's sources outside its project."""
    project = idf_project(tmp_path / "probe")
    (tmp_path / "common dir").mkdir()
    (tmp_path / "common dir/board.cmake").write_text("set(BOARD_LEDS 8)\n")
    cmake = project / "CMakeLists.txt"
    cmake.write_text('include("${CMAKE_CURRENT_LIST_DIR}/../common dir/board.cmake")\n' + cmake.read_text())
    (project / "main/idf_component.yml").write_text("dependencies: {}\n")
    subprocess.run(["chown", "-R", f"{USER_UID}:{USER_UID}", str(tmp_path)], check=True)
    built = subprocess.run(
        ["docker", "run", "--rm", "-u", f"{USER_UID}:{USER_UID}", "-e", "HOME=/tmp", "-v", f"{tmp_path}:/src",
         double[0], "idf.py", "-C", "/src/probe", "-B", "/src/probe/build", "reconfigure"],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert built.returncode == 0, built.stdout[-2000:] + built.stderr
    (rule,) = [line for line in (project / "build/build.ninja").read_text().splitlines() if "RERUN_CMAKE" in line]
    assert rule.startswith("build build.ninja: RERUN_CMAKE | ") and rule.endswith(" CMakeCache.txt"), rule
    for read in ("/src/common$ dir/board.cmake", "/src/probe/CMakeLists.txt", "/src/probe/main/CMakeLists.txt",
                 "/src/probe/main/idf_component.yml"):  # fmt: skip
        assert f" {read} " in rule, rule
