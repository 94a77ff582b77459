#!/usr/bin/env bash
# Host checks of the firmware under firmware/, no ESP-IDF needed:
#   1. build the hardware-free logic with the host compiler (plain and
#      ASan+UBSan) and run the tests under ctest;
#   2. esp-idf-kconfig's checker (kconfcheck) and parser on every Kconfig file;
#   3. catkin_pkg validation of every firmware package.xml;
#   4. espdock conventions: app layout, ROS names, colcon.meta sizing.
# Usage: tests/firmware/run.sh [BUILD_DIR]   (default build/host-tests)
# Needs cmake, a C compiler with ASan/UBSan, and the pip packages
# esp-idf-kconfig and catkin_pkg in one of: $PYTHON, the repo's .venv, python3.
# Exits non-zero on any failure.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
repo="$(cd "$here/../.." && pwd)"
firmware="$repo/firmware"
camera_msg="$repo/ws/src/custom_interface/msg/CameraConfig.msg"
build_dir="${1:-build/host-tests}"

mkdir -p "$build_dir"
build_dir="$(cd "$build_dir" && pwd)"

failed=()

step() {
    local name="$1"
    shift
    echo "==> $name"
    if "$@"; then
        echo "==> $name: passed"
    else
        echo "==> $name: FAILED" >&2
        failed+=("$name")
    fi
}

build_and_test() {
    cmake -S "$here" -B "$build_dir/cmake" -DCMAKE_BUILD_TYPE=Debug >/dev/null &&
        cmake --build "$build_dir/cmake" --parallel &&
        (cd "$build_dir/cmake" && ctest --output-on-failure)
}

# kconfcheck writes "<file>.new" suggestion files next to what it checks:
# check copies in the build directory so the source tree stays clean.
kconfig_style() {
    local copies=() file rel
    rm -rf "$build_dir/kconfcheck"
    for file in "${kconfig_files[@]}"; do
        rel="${file#"$repo"/}"
        mkdir -p "$build_dir/kconfcheck/$(dirname "$rel")"
        cp "$file" "$build_dir/kconfcheck/$rel"
        copies+=("$build_dir/kconfcheck/$rel")
    done
    "$python" -m kconfcheck "${copies[@]}"
}

# `make test` runs this without activating the venv it installed the
# packages into, so look there too before the system interpreter.
pick_python() {
    local candidate
    for candidate in "${PYTHON:-}" "$repo/.venv/bin/python" python3; do
        if [ -n "$candidate" ] && "$candidate" -c 'import kconfcheck, catkin_pkg' 2>/dev/null; then
            echo "$candidate"
            return 0
        fi
    done
    return 1
}

if ! python="$(pick_python)"; then
    echo "error: no Python with esp-idf-kconfig and catkin_pkg (tried \$PYTHON, .venv, python3);" \
         "run: python3 -m pip install esp-idf-kconfig catkin_pkg" >&2
    exit 2
fi
echo "==> using $python"

mapfile -t kconfig_files < <(find "$firmware" -type f \( -name 'Kconfig' -o -name 'Kconfig.*' \) \
    ! -name '*.new' | sort)
mapfile -t package_files < <(find "$firmware" -mindepth 2 -maxdepth 2 -name package.xml | sort)
if [ "${#kconfig_files[@]}" -eq 0 ] || [ "${#package_files[@]}" -eq 0 ]; then
    echo "error: no Kconfig or package.xml files found under $firmware" >&2
    exit 2
fi

step "host logic tests (ctest)" build_and_test
step "Kconfig style (kconfcheck)" kconfig_style
step "Kconfig parse" "$python" "$here/static_checks.py" kconfig "${kconfig_files[@]}"
step "package.xml (catkin_pkg)" "$python" "$here/static_checks.py" package-xml "${package_files[@]}"
step "firmware conventions" "$python" "$here/static_checks.py" apps "$firmware" "$camera_msg"

if [ "${#failed[@]}" -ne 0 ]; then
    echo "firmware host checks FAILED: ${failed[*]}" >&2
    exit 1
fi
echo "firmware host checks passed"
