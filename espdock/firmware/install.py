"""Installing a built firmware package into ws/install the way colcon installs a package.

ROS tools then find it like any other package (ament index, colcon's setup scripts,
`get_package_share_directory`), and its flashable artefacts sit under
share/<pkg>/firmware/. That directory is a symlink swapped in one rename, so a
reader sees the old firmware or the new one, never half of each; one that reads it in several
steps (a flash, then its verify) holds the version it began with (installed_version), which an
install meanwhile leaves for the next one to remove.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import shutil
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from espdock import durable
from espdock.errors import BuildFailed
from espdock.firmware.transport import TRANSPORT_RECORD, built_transport_record
from espdock.layout import FIRMWARE_DIR
from espdock.workspace import give_tree


def flash_file_names(flasher_args: dict) -> list[str]:
    """The files FLASHER_ARGS (a parsed flasher_args.json) has esptool write, relative to its directory."""
    named = flasher_args.get("flash_files")
    return sorted({str(name) for name in named.values()}) if isinstance(named, dict) else []


def firmware_files(build_dir: Path) -> list[str]:
    """The artefacts to install, relative to BUILD_DIR, as flasher_args.json names them."""
    flasher_args = build_dir / "flasher_args.json"
    try:
        args = json.loads(flasher_args.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise BuildFailed(f"{flasher_args} is missing or unreadable after the build: {exc}") from exc
    files = {"flasher_args.json", *flash_file_names(args)}
    for optional in ("flash_args", "project_description.json"):
        if (build_dir / optional).is_file():
            files.add(optional)
    app = args.get("app", {}).get("file", "")
    elf = Path(app).with_suffix(".elf").as_posix() if app else ""
    if elf and (build_dir / elf).is_file():
        files.add(elf)  # monitors decode backtraces with it
    missing = sorted(f for f in files if not (build_dir / f).is_file())
    if missing:
        raise BuildFailed(f"the build in {build_dir} did not write {', '.join(missing)}")
    return sorted(files)


def install_firmware(
    package: str,
    manifest: Path,
    build_dir: Path,
    install_base: Path,
    run_depends: tuple[str, ...],
    owner: tuple[int, int] | None,
    prefix: Path | None = None,
    workspace_root: Path | None = None,
) -> Path:
    """Install PACKAGE's artefacts from BUILD_DIR under INSTALL_BASE/<package> (or PREFIX: colcon's
    merged layout installs every package into the install base itself); return the firmware dir.
    WORKSPACE_ROOT (default: the install base's parent) is the workspace its `ros2 run` commands name."""
    prefix = prefix if prefix is not None else install_base / package
    share = prefix / "share" / package
    if not install_base.is_dir():
        install_base.mkdir(parents=True)
        if owner is not None:
            os.chown(install_base, *owner)
    share.mkdir(parents=True, exist_ok=True)
    files = firmware_files(build_dir)
    # Not in the digest: the same files are the same firmware, whose transport is in its app.
    transport = built_transport_record(build_dir)
    name = f".{FIRMWARE_DIR}-{_files_digest(build_dir, files)}"
    version_dir = share / name
    if version_dir.is_dir() and (altered_since_installed(version_dir) or _record(version_dir) != transport):
        # Its files edited by hand since: the build's go in again (beside it while a flash reads
        # it). Kept as they were, the build said it installed firmware it had not. So with a
        # record of another espdock's (one before the domain was in it) beside the same files.
        _remove_unless_in_use(version_dir)
        if version_dir.exists():
            version_dir = share / f"{name}-{uuid.uuid4().hex[:8]}"
    if not version_dir.is_dir():
        staging = share / f".{FIRMWARE_DIR}-staging-{uuid.uuid4().hex[:8]}"
        try:
            for rel in files:
                (staging / rel).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(build_dir / rel, staging / rel)
            if transport is not None:
                (staging / TRANSPORT_RECORD).write_bytes(transport)
            # The swapped-in firmware must be whole after a power cut: its files, then the names.
            durable.sync_tree(staging)
            staging.rename(version_dir)
            durable.sync_dir(share)
        finally:
            shutil.rmtree(staging, ignore_errors=True)
    _swap_symlink(share / FIRMWARE_DIR, version_dir.name)
    for stale in share.glob(f".{FIRMWARE_DIR}-*"):
        if stale != version_dir:
            _remove_unless_in_use(stale)
    for link in share.glob(f".{FIRMWARE_DIR}.*"):  # an unfinished _swap_symlink (espdock killed)
        link.unlink(missing_ok=True)
    _write_colcon_metadata(package, manifest, prefix, run_depends)
    write_package_commands(package, prefix, workspace_root or install_base.parent)
    if owner is not None:
        give_tree(prefix, owner)
    return share / FIRMWARE_DIR


# `ros2 run <package> <command> ARGS` runs `espdock <command> <package> ... ARGS`; idf.py's own
# arguments go after espdock's `--`.
PACKAGE_COMMANDS = {"idf": ("idf", "--"), "flash": ("flash",), "monitor": ("monitor",)}

_COMMAND_SCRIPT = """#!/bin/sh
# Generated by espdock: `ros2 run {package} {name} ARGS` is `espdock {name} {package} ARGS`
# for the workspace this package is installed in (found from this file's place, so the
# install tree stays the same wherever the workspace is).
here=$(CDPATH= cd -- "$(dirname -- "$0")" && pwd -P) || exit 1
if ! command -v espdock >/dev/null 2>&1; then
    echo "{name}: espdock is not on PATH; activate the venv it is installed in" >&2
    exit 127
fi
exec espdock {argv} --workspace "$here/{workspace}" {separator}"$@"
"""


# What decides the commands' files, for the install stamp.
COMMANDS_SOURCE = (_COMMAND_SCRIPT + repr(sorted(PACKAGE_COMMANDS.items()))).encode()


def write_package_commands(package: str, prefix: Path, workspace_root: Path) -> None:
    """PREFIX/lib/PACKAGE/{idf,flash,monitor}: where `ros2 run` looks for a package's executables.
    They name WORKSPACE_ROOT relative to themselves (the same in every clone of one layout)."""
    lib = prefix / "lib" / package
    lib.mkdir(parents=True, exist_ok=True)
    workspace = Path(os.path.relpath(workspace_root.resolve(), lib.resolve())).as_posix()
    for name, (command, *separator) in PACKAGE_COMMANDS.items():
        script = lib / name
        text = _COMMAND_SCRIPT.format(
            package=package,
            name=name,
            argv=f"{command} {package}",
            workspace=workspace,
            separator="".join(f"{s} " for s in separator),
        )
        if not script.is_file() or script.read_text() != text:
            script.write_text(text)
        script.chmod(0o755)


def _files_digest(directory: Path, files: list[str]) -> str:
    """What an install names its version directory by: a digest of FILES (under DIRECTORY), names and contents."""
    digest = hashlib.sha256()
    for rel in files:
        digest.update(rel.encode() + b"\0" + (directory / rel).read_bytes())
    return digest.hexdigest()[:16]


def _record(version: Path) -> bytes | None:
    """The TRANSPORT_RECORD installed in VERSION, or None."""
    try:
        return (version / TRANSPORT_RECORD).read_bytes()
    except OSError:
        return None


def altered_since_installed(version: Path) -> bool:
    """Whether the firmware files in VERSION (a directory installed_version gave) are no longer
    the ones espdock installed there, whose digest names it: a file edited or replaced by hand.
    The next install of the same build puts the build's files back."""
    prefix = f".{FIRMWARE_DIR}-"
    if not version.name.startswith(prefix):
        return False  # not a version directory (an install before versions, or none)
    try:
        return _files_digest(version, firmware_files(version)) != version.name.removeprefix(prefix)[:16]
    except (OSError, BuildFailed):
        return True  # a file it names is gone: not what was installed


@contextmanager
def installed_version(firmware_dir: Path) -> Iterator[Path]:
    """The version directory the installed FIRMWARE_DIR (share/<pkg>/firmware) names now, kept
    until the block ends: an install swapping in new firmware meanwhile leaves it for the next to
    remove. A flash runs esptool twice (write, then verify) and a swap between the two had the
    verify read the new firmware: "verify FAILED (digest mismatch)" of a board written whole.
    FIRMWARE_DIR itself where nothing is installed (the caller says so) or it is no symlink."""
    for _ in range(10):
        if not firmware_dir.is_symlink():
            yield firmware_dir
            return
        # Not resolve(): the workspace's own path may lead through links, and the containers see
        # it by that path.
        version = firmware_dir.parent / os.readlink(firmware_dir)
        try:
            fd = os.open(version, os.O_RDONLY | os.O_DIRECTORY)
        except FileNotFoundError:  # swapped and removed since the link was read
            continue
        except OSError:  # not to be opened (another user's, a file system without locks): unpinned
            break
        try:
            with contextlib.suppress(OSError):  # a file system without locks: read, not held
                fcntl.flock(fd, fcntl.LOCK_SH)  # waits while an install removes it
            if (version / "flasher_args.json").is_file():  # removed only under the exclusive lock
                yield version
                return
        finally:
            os.close(fd)
    yield firmware_dir  # as before, unpinned: swapped ten times over while it was read, or not to be held


def _remove_unless_in_use(version: Path) -> None:
    """Remove the firmware version directory VERSION unless installed_version holds it."""
    try:
        fd = os.open(version, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:  # no directory to hold (a file), or not to be opened: none holds it
        shutil.rmtree(version, ignore_errors=True)
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return
        except OSError:  # a file system without locks: as before
            pass
        shutil.rmtree(version, ignore_errors=True)
    finally:
        os.close(fd)


def _swap_symlink(link: Path, target: str) -> None:
    if link.is_dir() and not link.is_symlink():
        shutil.rmtree(link)  # a plain directory left by something else
    temporary = link.with_name(f".{link.name}.{uuid.uuid4().hex[:8]}")
    temporary.symlink_to(target)
    durable.replace(temporary, link)


def _write_colcon_metadata(package: str, manifest: Path, prefix: Path, run_depends: tuple[str, ...]) -> None:
    """The files colcon and ament write for an installed package, so setup scripts and ament_index find it."""
    share = prefix / "share" / package
    shutil.copy2(manifest, share / "package.xml")
    index = prefix / "share" / "ament_index" / "resource_index" / "packages" / package
    index.parent.mkdir(parents=True, exist_ok=True)
    index.write_text("")
    colcon = prefix / "share" / "colcon-core" / "packages" / package
    colcon.parent.mkdir(parents=True, exist_ok=True)
    colcon.write_text(":".join(run_depends))
    hooks = share / "hook"
    hooks.mkdir(exist_ok=True)
    (hooks / "ament_prefix_path.dsv").write_text("prepend-non-duplicate;AMENT_PREFIX_PATH;\n")
    (hooks / "ament_prefix_path.sh").write_text(
        '# generated by espdock\n_colcon_prepend_unique_value AMENT_PREFIX_PATH "$COLCON_CURRENT_PREFIX"\n'
    )
    (share / "package.dsv").write_text(
        f"source;share/{package}/hook/ament_prefix_path.dsv\nsource;share/{package}/hook/ament_prefix_path.sh\n"
    )
