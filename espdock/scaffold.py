"""`espdock new`: a firmware package from the template, with a name that works on both sides."""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from importlib import resources
from pathlib import Path

from espdock.errors import ConfigError, WorkspaceError
from espdock.workspace import Workspace

# REP 144: lower case letters, digits and underscores, starting with a letter, no "__".
PACKAGE_NAME = re.compile(r"^[a-z][a-z0-9_]*$")
TEMPLATE = "templates/firmware"
# A directory, a CMake project and a C identifier prefix: long names break none of them
# before the file system's 255 bytes do, but nobody types more than this.
MAX_NAME = 64


def validate_package_name(name: str) -> None:
    """Refuse NAME unless it is a valid ROS 2 package name (REP 144)."""
    problem = None
    if not PACKAGE_NAME.match(name):
        problem = "use lower case letters, digits and underscores, starting with a letter"
    elif len(name) > MAX_NAME:
        problem = f"at most {MAX_NAME} characters"
    elif "__" in name:
        problem = "no two underscores in a row"
    elif name.endswith("_"):
        problem = "no trailing underscore"
    if problem:
        raise ConfigError(f"'{name}' is not a valid ROS package name: {problem}", "For example: camera_node.")


def create_firmware_package(
    workspace: Workspace, name: str, depends: tuple[str, ...], owner: tuple[int, int] | None = None
) -> Path:
    """Write firmware/NAME from the template; refuse an existing directory. Returns the new directory.

    OWNER (uid, gid), when given, gets the new files (root creating them for someone).
    """
    validate_package_name(name)
    for dep in depends:
        validate_package_name(dep)
    destination = workspace.firmware_dir / name
    if destination.exists():
        raise WorkspaceError(f"{destination} already exists", "Pick another name, or remove that directory.")
    extra = "".join(f"  <depend>{d}</depend>\n" for d in dict.fromkeys(depends) if d != "std_msgs")
    template = resources.files("espdock").joinpath(TEMPLATE)
    try:
        workspace.firmware_dir.mkdir(parents=True, exist_ok=True)
        # Written next to its final place and renamed, so a failure leaves no half package.
        staging = Path(tempfile.mkdtemp(prefix=f".{name}-", dir=workspace.firmware_dir))
    except OSError as exc:
        raise WorkspaceError(
            f"cannot create {destination}: {exc.strerror or exc}",
            f"{workspace.firmware_dir} must be a directory you can write to.",
        ) from None
    try:
        _render(template, staging, {"@NAME@": name, "@DEPENDS@\n": extra})
        # mkdtemp made it private; the package gets the same mode as any new directory.
        umask = os.umask(0)
        os.umask(umask)
        staging.chmod(0o777 & ~umask)
        if owner is not None:
            for path in (staging, *staging.rglob("*")):
                os.lchown(path, *owner)
        staging.rename(destination)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return destination


def _render(source, destination: Path, replacements: dict[str, str]) -> None:
    for entry in source.iterdir():
        target = destination / entry.name
        if entry.is_dir():
            target.mkdir()
            _render(entry, target, replacements)
            continue
        text = entry.read_text()
        for placeholder, value in replacements.items():
            text = text.replace(placeholder, value)
        target.write_text(text)
