"""What a CMake build dir says its package read of the workspace outside its directory, in the
files CMake's Makefile generator writes (as CMake 3.31 in the ROS image writes them)."""

from __future__ import annotations

from pathlib import Path

from espdock.ros.cmake_inputs import outside_inputs

MAKEFILE_CMAKE = """# CMAKE generated file: DO NOT EDIT!
set(CMAKE_DEPENDS_GENERATOR "Unix Makefiles")

# The top level Makefile was generated from the following files:
set(CMAKE_MAKEFILE_DEPENDS
  "CMakeCache.txt"
  "/opt/espdock/venv/share/ament_cmake_core/cmake/ament_cmake_coreConfig.cmake"
  "/workspace/ws/src/repo/cmake/label.cmake"
  "/workspace/ws/src/repo/tool/CMakeLists.txt"
  )
"""
DEPEND_INFO = """
# The set of dependency files which are needed:
set(CMAKE_DEPENDS_DEPENDENCY_FILES
  "/workspace/ws/src/repo/tool/src/main.c" "CMakeFiles/tool.dir/src/main.c.o" "gcc" "CMakeFiles/tool.dir/src/main.c.o.d"
  )
"""
DEPFILE = """CMakeFiles/tool.dir/src/main.c.o: \\
 /workspace/ws/src/repo/tool/src/main.c /usr/include/stdio.h \\
 /workspace/ws/src/repo/tool/../include/with\\ space.h \\
 /workspace/ws/build/espdock-ros/tool/generated.h
"""
VERIFY_GLOBS = """cmake_policy(SET CMP0009 NEW)

# SOURCES at CMakeLists.txt:5 (file)
file(GLOB NEW_GLOB LIST_DIRECTORIES true "/workspace/ws/src/repo/common/*.c")
set(OLD_GLOB
  "/workspace/ws/src/repo/common/one.c"
  )
"""
INSTALL = """# Install script for directory: /workspace/ws/src/repo/tool
  file(INSTALL DESTINATION "${CMAKE_INSTALL_PREFIX}/share/tool" TYPE DIRECTORY FILES "/workspace/ws/src/repo/config")
  file(INSTALL DESTINATION "${CMAKE_INSTALL_PREFIX}/lib/tool" TYPE EXECUTABLE FILES
       "/workspace/ws/build/espdock-ros/tool/tool")
"""


def test_configure_inputs_current_objects_installed_directories_and_globs_count(tmp_path: Path):
    root = tmp_path
    for rel in ("cmake/label.cmake", "tool/CMakeLists.txt", "tool/src/main.c", "include/with space.h",
                "config/a.yaml", "common/one.c", "tools/retired.c"):  # fmt: skip
        (root / "ws/src/repo" / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / "ws/src/repo" / rel).write_text(rel)
    build = root / "ws/build/espdock-ros/tool"
    (build / "CMakeFiles/tool.dir/src").mkdir(parents=True)
    (build / "CMakeFiles/Makefile.cmake").write_text(MAKEFILE_CMAKE)
    (build / "CMakeFiles/TargetDirectories.txt").write_text(
        "/workspace/ws/build/espdock-ros/tool/CMakeFiles/tool.dir\n"
    )
    (build / "CMakeFiles/tool.dir/DependInfo.cmake").write_text(DEPEND_INFO)
    (build / "CMakeFiles/tool.dir/src/main.c.o.d").write_text(DEPFILE)
    # A target removed since: its directory and depfile stay, and are no input.
    (build / "CMakeFiles/old.dir").mkdir()
    (build / "CMakeFiles/old.dir/retired.c.o.d").write_text("x.o: /workspace/ws/src/repo/tools/retired.c\n")
    (build / "CMakeFiles/VerifyGlobs.cmake").write_text(VERIFY_GLOBS)
    (build / "cmake_install.cmake").write_text(INSTALL)
    outputs = [root / "ws" / name for name in ("build", "install", "log")]
    found = outside_inputs(build, root, root / "ws/src/repo/tool", outputs)
    assert found == [
        "ws/src/repo/cmake/label.cmake",
        "ws/src/repo/common/",
        "ws/src/repo/common/one.c",
        "ws/src/repo/config/",
        "ws/src/repo/config/a.yaml",
        "ws/src/repo/include/with space.h",
    ]
