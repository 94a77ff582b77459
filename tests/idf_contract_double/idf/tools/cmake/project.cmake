# contract double: stands in for ESP-IDF v5.3.5's tools/cmake/project.cmake, because ESP-IDF
# cannot be fetched here. The double's idf.py reads a project's CMakeLists.txt itself and only
# checks that this file is include()d before project(). Run by a real CMake, it stops:
message(FATAL_ERROR
    "This is the espdock IDF contract double (no ESP-IDF build system, no cross compiler): "
    "build with idf.py, which the double implements, not with cmake.")
