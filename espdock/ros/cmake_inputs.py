"""What a CMake package's last build read of the workspace outside the package's own directory.

Monorepos keep what their packages share beside them: `include(../cmake/warnings.cmake)`, a
`common/include` of headers, a source compiled into two packages. make knows those files (CMake
lists the files its configure read, the compilers' depfiles the headers and sources each object
was made of), and a native `colcon build` rebuilds when one changes; a stamp of the package's
directory alone would call the package up to date, and keep the old binary. The build's own
lists are read back from its build dir, so the stamp covers what the build read, no more.
"""

from __future__ import annotations

import hashlib
import posixpath
import re
from collections.abc import Collection, Iterable
from pathlib import Path

from espdock.layout import WORKSPACE_MOUNT

# CMake's Makefile generator: the files a configure read, which make re-runs CMake on.
MAKEFILE_DEPENDS = re.compile(r"^set\(CMAKE_MAKEFILE_DEPENDS\n(.*?)^\s*\)", re.MULTILINE | re.DOTALL)
# A path in a make rule: backslash-escaped characters (a space) or anything but whitespace.
RULE_WORD = re.compile(r"(?:\\.|[^\s\\])+")


def outside_inputs(build_dir: Path, root: Path, package_dir: Path, outputs: Collection[Path]) -> list[str]:
    """The files under ROOT (the workspace, mounted at WORKSPACE_MOUNT in the build container)
    that the build in BUILD_DIR read outside PACKAGE_DIR and outside OUTPUTS (colcon's build,
    install and log dirs, which are outputs), relative to ROOT. [] where BUILD_DIR holds no
    Makefile generator's build (Ninja's keeps its dependencies in a binary log)."""
    cmake_files = build_dir / "CMakeFiles"
    try:
        listed = MAKEFILE_DEPENDS.search((cmake_files / "Makefile.cmake").read_text(errors="surrogateescape"))
    except OSError:
        return []
    paths = {line.strip().strip('"') for line in listed.group(1).splitlines()} if listed else set()
    # Each object's depfile (CMake's compiler_depend mode, 3.20 on): its source and every header.
    for depfile in cmake_files.rglob("*.d"):
        try:
            paths.update(_rule_inputs(depfile.read_text(errors="surrogateescape")))
        except OSError:
            continue
    prefix = WORKSPACE_MOUNT + "/"
    found = set()
    for path in map(posixpath.normpath, paths):
        if not path.startswith(prefix):
            continue  # the image's (/opt/ros, /usr): its tag is in the stamp already
        host = root / path[len(prefix) :]
        if not any(host.is_relative_to(inside) for inside in (package_dir, *outputs)):
            found.add(host.relative_to(root).as_posix())
    return sorted(found)


def _rule_inputs(text: str) -> list[str]:
    """The prerequisites of the make rules in TEXT (a compiler's -MD output)."""
    inputs = []
    for rule in text.replace("\\\n", " ").splitlines():
        _, colon, prerequisites = rule.partition(": ")
        if colon:
            inputs += [re.sub(r"\\(.)", r"\1", word).replace("$$", "$") for word in RULE_WORD.findall(prerequisites)]
    return inputs


def file_digests(root: Path, paths: Iterable[str]) -> dict[str, str]:
    """Each of PATHS (relative to ROOT) with its content's sha256; a file gone, as gone."""
    digests = {}
    for rel in paths:
        try:
            digests[rel] = hashlib.sha256((root / rel).read_bytes()).hexdigest()
        except OSError:
            digests[rel] = "not a file"
    return digests


def inputs_digest(root: Path, paths: Iterable[str]) -> str:
    """sha256 over PATHS (relative to ROOT) and their contents (file_digests)."""
    digest = hashlib.sha256()
    for rel, content in sorted(file_digests(root, paths).items()):
        digest.update(f"{rel}\0{content}\n".encode(errors="surrogateescape"))
    return digest.hexdigest()
