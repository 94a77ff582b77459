"""What a workspace's interface packages refer to in other packages, read from their .msg, .srv,
.action and .idl files: rosidl needs each such package found (find_package) before it runs, which
only a package.xml dependency promises."""

from __future__ import annotations

import re
from collections.abc import Mapping

from espdock.workspace import Package

# A field's type in rosidl's message syntax: `pkg/Type` or `pkg/msg/Type`, with an array suffix
# (`[]`, `[3]`, `[<=3]`) or none. A type without a package is the package's own.
_FIELD = re.compile(r"^\s*(?P<package>[A-Za-z][A-Za-z0-9_]*)/(?:msg/)?(?P<type>[A-Za-z][A-Za-z0-9_]*)(?:\[[^\]]*\])?\s")
# An IDL file includes each type it uses from another package.
_INCLUDE = re.compile(
    r'^\s*#include\s+[<"](?P<package>[A-Za-z][A-Za-z0-9_]*)/(?:msg|srv|action)/(?P<type>\w+)\.idl[>"]'
)
_SUFFIXES = (".msg", ".srv", ".action")


def references(files: Mapping[str, bytes]) -> dict[str, tuple[str, str]]:
    """The packages FILES' interfaces (by path in their package) use types of: each with the
    first such type and the file it is in."""
    found: dict[str, tuple[str, str]] = {}
    for rel, data in sorted(files.items()):
        pattern = _FIELD if rel.endswith(_SUFFIXES) else _INCLUDE if rel.endswith(".idl") else None
        if pattern is None:
            continue
        for line in data.decode("utf-8", "replace").splitlines():
            if match := pattern.match(line):
                found.setdefault(match.group("package"), (f"{match.group('package')}/{match.group('type')}", rel))
    return found


def undeclared(package: Package, files: Mapping[str, bytes]) -> list[str]:
    """What PACKAGE's interface FILES use of packages its package.xml does not depend on, one line
    each. colcon then orders the two as unrelated: an old install/ of the other hides it, a clean
    build fails or not by the order it happens to take, rosdep installs nothing for it, and
    micro-ROS's library build, which has no old install, fails on it."""
    declared = package.depends - package.test_only_depends
    return [
        f"{package.name} uses {used} ({rel}), but its package.xml does not depend on {other}: colcon may "
        f"build {package.name} first, or against an old install of {other}, and micro-ROS's library build "
        f"fails on it. Add <depend>{other}</depend> to {package.path / 'package.xml'}"
        for other, (used, rel) in sorted(references(files).items())
        if other != package.name and other not in declared
    ]
