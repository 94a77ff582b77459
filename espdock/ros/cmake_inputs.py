"""What a CMake package's last build read of the workspace outside the package's own directory.

Monorepos keep what their packages share beside them: `include(../cmake/warnings.cmake)`, a
`common/include` of headers, a source compiled into two packages, a `config/` both install. make
knows those files (CMake lists the files its configure read and those its install script
copies, the compilers' depfiles the headers and sources each object was made of), and a native
`colcon build` rebuilds and installs again when one changes; a stamp of the package's
directory alone would call the package up to date, and keep the old binary. The build's own
lists are read back from its build dir, so the stamp covers what the build read, no more.
"""

from __future__ import annotations

import hashlib
import posixpath
import re
from collections.abc import Collection, Iterable, Mapping
from pathlib import Path

from espdock.build.stamps import source_files
from espdock.layout import WORKSPACE_MOUNT

# CMake's Makefile generator: the files a configure read, which make re-runs CMake on.
MAKEFILE_DEPENDS = re.compile(r"^set\(CMAKE_MAKEFILE_DEPENDS\n(.*?)^\s*\)", re.MULTILINE | re.DOTALL)
# A target's DependInfo.cmake: source, object, compiler and depfile of each of its objects.
DEPENDENCY_FILES = re.compile(r"^set\(CMAKE_DEPENDS_DEPENDENCY_FILES\n(.*?)^\s*\)", re.MULTILINE | re.DOTALL)
QUOTED = re.compile(r'"([^"]*)"')
# CONFIGURE_DEPENDS globs, which make re-runs CMake for when their result changes.
VERIFIED_GLOB = re.compile(r'^file\(GLOB(?:_RECURSE)? NEW_GLOB\b[^"\n]*"([^"]+)"', re.MULTILINE)
# An install script's includes: the install scripts of the subdirectories.
INCLUDED = re.compile(r'^\s*include\("([^"]+/cmake_install\.cmake)"\)', re.MULTILINE)
# A path in a make rule: backslash-escaped characters (a space) or anything but whitespace.
RULE_WORD = re.compile(r"(?:\\.|[^\s\\])+")


def outside_inputs(build_dir: Path, root: Path, package_dir: Path, outputs: Collection[Path]) -> list[str]:
    """The files under ROOT (the workspace, mounted at WORKSPACE_MOUNT in the build container)
    that the build in BUILD_DIR read outside PACKAGE_DIR and outside OUTPUTS (colcon's build,
    install and log dirs, which are outputs), relative to ROOT: what its configure read, the
    sources and headers of its targets' objects, what it installs. [] where BUILD_DIR holds no
    Makefile generator's build (Ninja's keeps its dependencies in a binary log)."""
    cmake_files = build_dir / "CMakeFiles"
    listed = MAKEFILE_DEPENDS.search(_read(cmake_files / "Makefile.cmake"))
    if listed is None:
        return []
    paths = set(QUOTED.findall(listed.group(1)))
    # The targets the build has now (a target removed since keeps its directory, and its objects'
    # depfiles: they are no input any more).
    for target in _read(cmake_files / "TargetDirectories.txt").splitlines():
        if (directory := _host(target, root)) is None:
            continue
        files = DEPENDENCY_FILES.search(_read(directory / "DependInfo.cmake"))
        quads = QUOTED.findall(files.group(1)) if files else []
        # The depfiles are relative to the build dir of the target's directory, above its CMakeFiles/.
        for source, _, _, depfile in zip(*[iter(quads)] * 4, strict=False):
            paths.add(source)
            paths.update(_rule_inputs(_read(directory.parent.parent / depfile)))
    paths.update(_installed(build_dir / "cmake_install.cmake", root))
    # A glob's directory (up to its first wildcard): a file added there is one more input.
    globbed = {re.split(r"[*?\[]", pattern, maxsplit=1)[0].rpartition("/")[0] + "/"
               for pattern in VERIFIED_GLOB.findall(_read(cmake_files / "VerifyGlobs.cmake"))}  # fmt: skip
    found = set()
    for path in (*map(posixpath.normpath, paths), *globbed):
        if (host := _host(path, root)) is None:
            continue  # the image's (/opt/ros, /usr): its tag is in the stamp already
        if any(host.is_relative_to(inside) for inside in (package_dir, *outputs)):
            continue
        if host.is_dir():
            # A directory it installs (install(DIRECTORY ../config ...)) or globs: its files, and
            # which files it holds (LISTED), so that one added to it counts.
            found.add(host.relative_to(root).as_posix() + LISTED)
            found.update(f.relative_to(root).as_posix() for f in source_files(host))
        elif not path.endswith("/"):
            found.add(host.relative_to(root).as_posix())
    return sorted(found)


# The mark of a directory's entry in outside_inputs: digested by the files it holds.
LISTED = "/"


def _host(path: str, root: Path) -> Path | None:
    """Where PATH of the build container is on this machine: under ROOT, the workspace; None
    where it is not the workspace's."""
    prefix = WORKSPACE_MOUNT + "/"
    return root / posixpath.normpath(path)[len(prefix) :] if path.startswith(prefix) else None


def _read(path: Path) -> str:
    try:
        return path.read_text(errors="surrogateescape")
    except OSError:
        return ""


def _installed(script: Path, root: Path, seen: set[Path] | None = None) -> set[str]:
    """The files an install SCRIPT (cmake_install.cmake) and the subdirectories' it includes name."""
    seen = seen if seen is not None else set()
    if script in seen:
        return set()
    seen.add(script)
    text = _read(script)
    found = {path for path in QUOTED.findall(text) if path.startswith("/")}
    for included in INCLUDED.findall(text):
        if (host := _host(included, root)) is not None:
            found |= _installed(host, root, seen)
    return found


def _rule_inputs(text: str) -> list[str]:
    """The prerequisites of the make rules in TEXT (a compiler's -MD output)."""
    inputs = []
    for rule in text.replace("\\\n", " ").splitlines():
        _, colon, prerequisites = rule.partition(": ")
        if colon:
            inputs += [re.sub(r"\\(.)", r"\1", word).replace("$$", "$") for word in RULE_WORD.findall(prerequisites)]
    return inputs


def file_digests(root: Path, paths: Iterable[str], known: dict[str, str] | None = None) -> dict[str, str]:
    """Each of PATHS (relative to ROOT) with its content's sha256; a file gone, as gone. KNOWN:
    digests read before in the same run, taken as they are (packages share their files)."""
    known = known if known is not None else {}
    digests = {}
    for rel in paths:
        if rel not in known:
            if rel.endswith(LISTED):
                held = sorted(f.relative_to(root / rel).as_posix() for f in source_files(root / rel))
                known[rel] = hashlib.sha256("\n".join(held).encode(errors="surrogateescape")).hexdigest()
            else:
                try:
                    known[rel] = hashlib.sha256((root / rel).read_bytes()).hexdigest()
                except OSError:
                    known[rel] = "not a file"
        digests[rel] = known[rel]
    return digests


def fold(tree: str, outside: Mapping[str, str]) -> str:
    """A package's source digest: its directory's TREE digest, with the OUTSIDE files' digests
    (path -> sha256) where there are any."""
    if not outside:
        return tree
    digest = hashlib.sha256(f"{tree}\n".encode())
    for rel, content in sorted(outside.items()):
        digest.update(f"{rel}\0{content}\n".encode(errors="surrogateescape"))
    return digest.hexdigest()
