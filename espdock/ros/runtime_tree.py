"""What a runtime image takes from the install tree, standing alone, and the key and build
context made of it.

colcon's `--symlink-install` leaves install/ pointing elsewhere: ament_cmake installs symlinks
into build/ (compiled executables) and the sources (scripts, package.xml), and ament_python
installs in develop mode (an .egg-link and a PYTHONPATH hook naming build/PKG, whose modules are
symlinks into the sources). The build containers see those targets under the workspace mount;
the runtime image has neither build/ nor the sources. So every link that leaves the install
tree is copied in as what it points at, and a develop-mode package's modules and metadata land
in its site-packages, where Python and its console scripts find them. An edit to a linked source
file changes what is taken, so the next runtime image holds it, as a symlink install would.
"""

from __future__ import annotations

import hashlib
import os
import posixpath
from dataclasses import replace
from pathlib import Path

from espdock.build.stamps import content_sha256
from espdock.build.steps import ImageSpec
from espdock.errors import WorkspaceError
from espdock.images.keyed import image_mode
from espdock.layout import host_path
from espdock.ros.plan import RuntimeImage, runtime_image_spec
from espdock.workspace import Workspace, editor_leftover

# Links are followed this many times before one is taken for a loop.
_MAX_HOPS = 40


def _target(link: Path, root: Path) -> Path | None:
    """Where the symlink LINK ends on the host, its container paths under the workspace mount
    read under ROOT; None for a dangling link or a loop."""
    path = link
    for _ in range(_MAX_HOPS):
        if not path.is_symlink():
            return path if path.exists() else None
        text = os.readlink(path)
        if posixpath.isabs(text):
            mapped = host_path(text, root)
            path = mapped if mapped is not None else Path(text)
        else:
            path = path.parent / text
        path = Path(os.path.normpath(path))
        # A directory on the way may itself be a link (build/PKG/module -> src/...).
        path = _through_parents(path, root)
    return None


def _through_parents(path: Path, root: Path) -> Path:
    for parent in reversed(path.parents):
        if parent.is_symlink():
            resolved = _target(parent, root)
            if resolved is not None:
                return resolved / path.relative_to(parent)
    return path


def _inside(path: Path, tree: Path) -> bool:
    return path == tree or tree in path.parents


def _walk(
    directory: Path, dest: str, root: Path, tree: Path, found: dict[str, Path | bytes], sources: bool = False
) -> None:
    """Add what DIRECTORY holds to FOUND under DEST, links that leave TREE resolved. SOURCES: a
    directory of the sources a symlink install leads to, whose hidden files (an editor's swap
    file, .mypy_cache, a .env) and editors' leftovers a copying install would not have taken."""
    for entry in sorted(directory.iterdir()):
        if entry.name == "__pycache__" or entry.name.endswith(".pyc"):
            continue
        if sources and (entry.name.startswith(".") or editor_leftover(entry.name)):
            continue
        rel = f"{dest}/{entry.name}"
        if entry.is_symlink():
            text = os.readlink(entry)
            if not posixpath.isabs(text) and _inside(Path(os.path.normpath(entry.parent / text)), tree):
                found[rel] = entry  # a link within the tree (a library's soname alias) stays a link
                continue
            if editor_leftover(entry.name):
                # ament_cmake's symlink install links each file of a directory it installs (an
                # ament_python_install_package module's swap file too): each write made a new image.
                continue
            resolved = _target(entry, root)
            if resolved is None:
                continue  # dangling where it was built too: nothing to take
            if resolved.is_dir():
                _walk(resolved, rel, root, resolved, found, sources=True)
            elif resolved.is_file():  # not a named pipe or socket in the sources: `run` hung reading one
                found[rel] = resolved
        elif entry.is_dir():
            _walk(entry, rel, root, tree, found, sources)
        elif entry.suffix == ".egg-link":
            _develop_package(entry, dest, root, found)
        elif entry.name == "package.dsv" and (kept := _own_hooks(entry)) is not None:
            found[rel] = kept
        elif entry.is_file():
            found[rel] = entry


def _own_hooks(package_dsv: Path) -> bytes | None:
    """PACKAGE_DSV without the hooks it sources from outside the package's prefix (a develop
    install's pythonpath_develop hook in build/, whose path the image does not have); None when
    it has none."""
    lines = package_dsv.read_text(errors="replace").splitlines(keepends=True)
    kept = [line for line in lines if not line.startswith("source;../")]
    return None if len(kept) == len(lines) else "".join(kept).encode()


def _develop_package(egg_link: Path, site_packages: str, root: Path, found: dict[str, Path | bytes]) -> None:
    """A package `setup.py develop` installed: its top-level modules and metadata from the
    directory the .egg-link names, into SITE_PACKAGES."""
    lines = egg_link.read_text(errors="replace").splitlines()
    named = lines[0].strip() if lines else ""
    directory = host_path(named, root) if posixpath.isabs(named) else None
    if directory is None or not directory.is_dir():
        return
    for info in sorted(directory.glob("*.egg-info")):
        _walk(info, f"{site_packages}/{info.name}", root, info, found)
        top_level = info / "top_level.txt"
        names = top_level.read_text().split() if top_level.is_file() else []
        for name in names:
            for candidate in (directory / name, directory / f"{name}.py"):
                resolved = _target(candidate, root) if candidate.is_symlink() else candidate
                if resolved is None or not resolved.exists():
                    continue
                if resolved.is_dir():
                    _walk(resolved, f"{site_packages}/{candidate.name}", root, resolved, found, sources=True)
                elif resolved.is_file():
                    found[f"{site_packages}/{candidate.name}"] = resolved


def runtime_files(install: Path, packages: tuple[str, ...], root: Path | None = None) -> dict[str, Path | bytes]:
    """What a runtime image takes from INSTALL (relative path -> the host file holding it, or the
    content itself where it is rewritten): colcon's
    top-level setup files and PACKAGES' trees (not the firmware packages', nor espdock's manifest),
    with links out of the tree resolved. ROOT: the workspace root the build containers mount."""
    root = root if root is not None else install.parent
    # colcon's own files at the top (setup scripts, COLCON_IGNORE); espdock's manifest is not.
    found: dict[str, Path | bytes] = {
        p.name: p for p in sorted(install.iterdir()) if p.is_file() and not p.name.startswith("espdock-")
    }
    for name in packages:
        if (install / name).is_dir():
            _walk(install / name, name, root, install / name, found)
    return found


def resolve_installed(path: Path, root: Path) -> Path | None:
    """PATH in an install tree as the runtime image will hold it: a link out of the tree followed
    (container paths read under ROOT); None when it points at nothing."""
    return _target(path, root) if path.is_symlink() else path


def runtime_spec(workspace: Workspace, step: RuntimeImage) -> ImageSpec:
    """The keyed runtime image for STEP's install trees as they are now."""
    step = installed_step(workspace, step)
    digest = runtime_install_digest(workspace.ws_dir / "install", step.packages, workspace.root)
    return runtime_image_spec(step, digest)


def runtime_install_digest(install: Path, packages: tuple[str, ...], root: Path | None = None) -> str:
    """sha256 over the paths, modes and contents of what a runtime image takes from INSTALL
    (ROOT: the workspace root, where links of a symlink install lead)."""
    digest = hashlib.sha256()
    for rel, path in runtime_files(install, packages, root).items():
        if isinstance(path, bytes):
            mode, content = 0o644, hashlib.sha256(path).digest()
        elif path.is_symlink():
            mode, content = 0o777, hashlib.sha256(os.readlink(path).encode()).digest()
        else:
            info = path.stat()
            mode, content = image_mode(info.st_mode), content_sha256(path, info)
        digest.update(f"{rel}\0{mode:o}\0".encode())
        digest.update(content)
    return digest.hexdigest()


def runtime_context(install: Path, step: RuntimeImage, root: Path | None = None) -> dict[str, Path | bytes]:
    """The runtime image's build context besides its Dockerfile: exactly the files
    runtime_install_digest hashed, under install/."""
    return {f"install/{rel}": path for rel, path in runtime_files(install, step.packages, root).items()}


def installed_step(workspace: Workspace, step: RuntimeImage) -> RuntimeImage:
    """STEP for the packages among its own that have an install tree; none at all is an error."""
    install = workspace.ws_dir / "install"
    present = tuple(name for name in step.packages if (install / name).is_dir())
    if step.packages and not present:
        raise WorkspaceError(f"no ROS package is installed in {install}", "Run `espdock build` to build them.")
    return replace(step, packages=present)
