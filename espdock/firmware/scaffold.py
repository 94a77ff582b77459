"""`espdock new`: a firmware package from the template, with a name that works on both sides."""

from __future__ import annotations

import contextlib
import difflib
import os
import posixpath
import re
import shutil
import subprocess
import tempfile
from importlib import resources
from pathlib import Path

from espdock.defaults import default_file
from espdock.errors import ConfigError, WorkspaceError
from espdock.firmware import transport
from espdock.firmware.plan import STANDARD_INTERFACES, check_micro_ros_target
from espdock.layout import CONFIG_FILE
from espdock.workspace import Package, PackageKind, Workspace

# REP 144: lower case letters, digits and underscores, starting with a letter, no "__".
PACKAGE_NAME = re.compile(r"^[a-z][a-z0-9_]*$")
TEMPLATE = "templates/firmware"
# The shared firmware component every espdock app builds on (Wi-Fi, agent reconnection).
COMPONENT = "espdock_uros"
# In the shared components' directory: colcon does not look inside.
COLCON_IGNORE = "COLCON_IGNORE"
# A directory, a CMake project and a C identifier prefix: long names break none of them
# before the file system's 255 bytes do, but nobody types more than this.
MAX_NAME = 64


def validate_package_name(name: str) -> None:
    """Refuse NAME unless it is a valid ROS 2 package name (REP 144)."""
    problem = None
    if not PACKAGE_NAME.match(name):
        problem = "use lower case letters, digits and underscores, starting with a letter"
    elif len(name) < 2:
        problem = "at least two characters"
    elif len(name) > MAX_NAME:
        problem = f"at most {MAX_NAME} characters"
    elif "__" in name:
        problem = "no two underscores in a row"
    elif name.endswith("_"):
        problem = "no trailing underscore"
    if problem:
        raise ConfigError(f"'{name}' is not a valid ROS package name: {problem}", "For example: camera_node.")


# Standard interface packages micro-ROS (jazzy) builds into every library: a firmware package
# may depend on these without the workspace holding them.
# Names that would sit where colcon's outputs or the shared components live.
RESERVED_NAMES = ("build", "install", "log", "components")


def firmware_home(workspace: Workspace, packages: tuple[Package, ...]) -> Path:
    """Where a new firmware package goes: beside the existing ones, else in a package path named
    firmware, else in the first package path."""
    existing = [p for p in packages if p.kind is PackageKind.FIRMWARE]
    if existing:
        return existing[0].path.parent
    named = [rel for rel in workspace.package_paths if Path(rel).name == "firmware"]
    return workspace.root / (named[0] if named else workspace.package_paths[0])


def check_new_package(name: str, depends: tuple[str, ...], packages: tuple[Package, ...]) -> None:
    """Refuse NAME if it is no ROS name, taken or reserved, and DEPENDS naming no interface package."""
    validate_package_name(name)
    by_name = {p.name: p for p in packages}
    if name in by_name:
        raise WorkspaceError(
            f"a package named '{name}' already exists ({by_name[name].path})", "Package names are unique; pick another."
        )
    if name in RESERVED_NAMES:
        raise ConfigError(f"'{name}' is reserved (colcon's outputs and shared components use it)", "Pick another name.")
    if name in STANDARD_INTERFACES:
        # Its package.xml would depend on itself (the template's std_msgs), and it would stand
        # where micro-ROS's own package of that name does.
        raise ConfigError(
            f"'{name}' is one of ROS's standard interface packages, built into micro-ROS", "Pick another name."
        )
    interfaces = sorted({*STANDARD_INTERFACES, *(p.name for p in packages if p.is_interface)})
    for dep in depends:
        validate_package_name(dep)
        if dep in interfaces:
            continue
        close = difflib.get_close_matches(dep, interfaces, n=3)
        why = "is not an interface package" if dep in by_name else "is neither in this workspace nor in micro-ROS"
        raise WorkspaceError(
            f"--depends {dep}: '{dep}' {why}",
            (f"Did you mean {', '.join(close)}? " if close else "")
            + f"Interface packages: {', '.join(p for p in interfaces if p not in STANDARD_INTERFACES) or 'none'} "
            f"in this workspace, and micro-ROS's standard ones ({', '.join(STANDARD_INTERFACES[:6])}, ...).",
        )


def create_firmware_package(
    workspace: Workspace,
    name: str,
    depends: tuple[str, ...],
    packages: tuple[Package, ...],
    owner: tuple[int, int] | None = None,
    target: str | None = None,
    link: str = transport.UDP,
    workspace_target: str | None = None,
) -> Path:
    """Write NAME from the template where the workspace's firmware goes (firmware_home), and the
    shared espdock_uros component beside it if missing. Returns the new package's directory.

    TARGET, when given, is the package's chip: CONFIG_IDF_TARGET in its sdkconfig.defaults, where
    IDF and espdock read it (other packages keep theirs); else WORKSPACE_TARGET (the setting) is.
    A chip the package could never build for (its transport, micro-ROS) is refused first.

    LINK is how the board reaches the agent (espdock.firmware.transport): a serial one is written into
    sdkconfig.defaults and app-colcon.meta (so that a plain `idf.py build` matches too).

    OWNER (uid, gid), when given, gets the new files (root creating them for someone).
    """
    check_new_package(name, depends, packages)
    if chip := target or workspace_target:
        transport.check_transport(name, link, chip, new=True)
        check_micro_ros_target(name, chip, "Give it --target")
    home = firmware_home(workspace, packages)
    if not (real := home.resolve()).is_relative_to(workspace.root.resolve()):
        # The build refuses a firmware project there (check_inside): say so before writing one.
        raise WorkspaceError(
            f"{home} leads outside the workspace ({real}): a firmware package there would not build, as the IDF "
            "containers see only the workspace (ROS packages may be linked in)",
            "Make a directory for firmware in the workspace and add it to package_paths in espdock.toml (`espdock "
            "new` puts firmware in one named firmware), then run it again. Nothing was written.",
        )
    destination = home / name
    if destination.exists():
        raise WorkspaceError(f"{destination} already exists", "Pick another name, or remove that directory.")
    extra = "".join(f"  <depend>{d}</depend>\n" for d in dict.fromkeys(depends) if d != "std_msgs")
    template = resources.files("espdock.firmware").joinpath(TEMPLATE)
    component = home / "components" / COMPONENT
    try:
        home.mkdir(parents=True, exist_ok=True)
        # Written next to their final places and renamed, so a failure leaves no half package.
        staging = Path(tempfile.mkdtemp(prefix=f".{name}-", dir=home))
    except OSError as exc:
        raise WorkspaceError(
            f"cannot create {destination}: {exc.strerror or exc}", f"{home} must be a directory you can write to."
        ) from None
    try:
        _render(template, staging / "package", {"@NAME@": name, "@DEPENDS@\n": extra})
        if target:
            defaults = staging / "package" / "sdkconfig.defaults"
            chip = f'# The chip this package builds for (`espdock new --target`).\nCONFIG_IDF_TARGET="{target}"\n\n'
            defaults.write_text(chip + defaults.read_text())
        if link != transport.UDP:
            _write_serial_transport(staging / "package", name, link)
        if not component.exists():
            shutil.copytree(default_file(f"firmware/components/{COMPONENT}"), staging / COMPONENT)
        umask = os.umask(0)
        os.umask(umask)
        for path in (staging, *staging.rglob("*")):
            # mkdtemp made it private; the files get the modes of any new file or directory.
            path.chmod((0o777 if path.is_dir() else 0o666) & ~umask)
            if owner is not None:
                os.lchown(path, *owner)
        if (staging / COMPONENT).exists():
            component.parent.mkdir(exist_ok=True)
            # colcon takes any directory with a CMakeLists.txt for a CMake package: a plain
            # `colcon build` would try the component with the host's CMake and fail.
            ignore = component.parent / COLCON_IGNORE
            ignore.touch()
            for path in (component.parent, ignore) if owner is not None else ():
                os.lchown(path, *owner)
            (staging / COMPONENT).rename(component)
        (staging / "package").rename(destination)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return destination


SERIAL_DEFAULTS = {
    transport.UART: (
        "# micro-ROS over a serial line: UART0, the board's USB-to-UART bridge, at 115200 baud\n"
        "# (`espdock agent --port /dev/ttyUSB0`). No Wi-Fi and nothing to provision.\n"
        "CONFIG_ESPDOCK_TRANSPORT_UART=y\nCONFIG_ESPDOCK_UART_PORT=0\nCONFIG_ESPDOCK_UART_BAUD=115200\n"
    ),
    transport.USB_SERIAL_JTAG: (
        "# micro-ROS over the chip's own USB port (USB-Serial-JTAG; esp32c3, esp32s3), seen by the\n"
        "# host as /dev/ttyACM<n> (`espdock agent --port /dev/ttyACM0`). No Wi-Fi, nothing to provision.\n"
        "CONFIG_ESPDOCK_TRANSPORT_USB_SERIAL_JTAG=y\n"
        "# The console stays on UART0: log lines on the link would cost XRCE frames.\n"
        "CONFIG_ESP_CONSOLE_SECONDARY_NONE=y\n"
    ),
}


def _write_serial_transport(package: Path, name: str, link: str) -> None:
    """Turn the UDP template into a serial one: its Kconfig choice, upstream's UART choice for the
    micro-ROS component, and a library with the custom transport."""
    defaults = package / "sdkconfig.defaults"
    lines = defaults.read_text().splitlines(keepends=True)
    # The template's opening comment is about Wi-Fi provisioning; the serial block replaces it.
    start = next((i for i, line in enumerate(lines) if line.startswith("# micro-ROS over Micro XRCE-DDS on Wi-Fi")), 0)
    end = start
    while end < len(lines) and lines[end].startswith("#"):
        end += 1
    text = "".join(lines[:start] + lines[end:]).replace(
        "CONFIG_MICRO_ROS_ESP_NETIF_WLAN=y\n", SERIAL_DEFAULTS[link] + "CONFIG_MICRO_ROS_ESP_UART_TRANSPORT=y\n"
    )
    defaults.write_text(text)
    meta = package / "app-colcon.meta"
    meta.write_text(transport.library_colcon_meta(name, meta.read_text(), link))


def _render(source, destination: Path, replacements: dict[str, str]) -> None:
    destination.mkdir(exist_ok=True)
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


CONFIG_TEMPLATE = """\
# espdock workspace settings (written by `espdock init`). Every key is optional;
# ESPDOCK_<KEY> variables and command-line options override them.
[espdock]
# Where packages are looked for, relative to this file: ROS packages and ESP-IDF
# firmware packages (<build_type>esp_idf</build_type>) alike, anywhere below.
package_paths = [{paths}]
# Where colcon's build/, install/ and log/ go.
colcon_root = "{colcon_root}"
# ESP32 chip target for firmware packages: esp32, esp32s3, esp32c3, ...
# target = "esp32"
# Behind a TLS-intercepting proxy: its CA bundle (default: the cert pip is configured with).
# ca_bundle = "/path/to/corporate-ca.pem"
# Make the runtime image of install/ (espdock/<name>:latest) with every build, so that plain
# `docker compose up` runs what the last build installed (else `espdock compose up` and
# `espdock run` make it when they start).
# runtime_image = true
"""


def init_workspace(directory: Path, owner: tuple[int, int] | None = None) -> tuple[Workspace, list[str]]:
    """Make DIRECTORY (empty, or an existing colcon workspace) an espdock workspace: a commented
    espdock.toml with the detected layout, and src/ where there is no package path yet. Only adds
    files: an existing espdock.toml is left as it is. Returns the workspace and what was created."""
    from espdock.workspace import CLASSIC_LAYOUT, COLCON_LAYOUT, check_utf8_path, ways_up

    resolved, logical = ways_up(directory)
    root = resolved[0]
    check_utf8_path(root)
    if not (root / CONFIG_FILE).exists():
        # Above it through links as they are, or as the shell reached it (a package linked into src/).
        if above := next((d for d in (*resolved[1:], *logical[1:]) if (d / CONFIG_FILE).is_file()), None):
            shown = root if above in resolved else f"{logical[0]} (through a link, {root})"
            raise WorkspaceError(
                f"{shown} is inside the espdock workspace {above}: a workspace in it would take over every "
                "command run below it",
                f"Run espdock in {above} (`espdock new`, `espdock build`, `espdock init --compose` for its "
                "compose file); to start another workspace, init a directory outside it.",
            )
        held = sorted(d.name for d in root.iterdir() if (d / "package.xml").is_file()) if root.is_dir() else []
        if root.name == "src" and held:
            raise WorkspaceError(
                f"{root} holds packages ({', '.join(held[:3])}{', ...' if len(held) > 3 else ''}): it is the "
                "src/ of a colcon workspace, not one",
                f"Run `espdock init {root.parent}`: the colcon workspace around it.",
            )
    created: list[str] = []
    try:
        if not root.exists():
            root.mkdir(parents=True)
            created.append(str(root))
        paths, colcon_root = CLASSIC_LAYOUT if (root / "ws" / "src").is_dir() else COLCON_LAYOUT
        config = root / CONFIG_FILE
        if config.exists():
            return Workspace(root).with_layout(None, None), created
        for rel in paths:
            if not (root / rel).exists():
                (root / rel).mkdir(parents=True)
                created.append(f"{rel}/")
        with config.open("x") as out:  # never overwrites
            out.write(CONFIG_TEMPLATE.format(paths=", ".join(f'"{p}"' for p in paths), colcon_root=colcon_root))
        created.append(CONFIG_FILE)
        if not os.path.lexists(root / GITIGNORE):  # a link, even a dangling one, is the user's
            # Without it a `git stash -u` took the whole build along, and its pop then failed on
            # every file the next build had made again.
            outputs = posixpath.normpath(f"/{colcon_root}")
            (root / GITIGNORE).write_text(
                GITIGNORE_TEMPLATE.format(
                    *(_ignore_line(posixpath.join(outputs, d)) for d in ("build", "install", "log"))
                )
            )
            created.append(GITIGNORE)
        # Not inside a repository that says how its files are checked out: the deeper file
        # would win over its rules (a .bat's CRLF, a -text file).
        if not _attributes_above(root):
            (root / GITATTRIBUTES).write_text(GITATTRIBUTES_TEXT)
            created.append(GITATTRIBUTES)
    except OSError as exc:
        undo_init(root, created)
        raise WorkspaceError(f"cannot make {root} a workspace: {exc.strerror or exc}") from None
    if owner is not None:
        for rel in created:
            path = root / rel.rstrip("/") if not Path(rel).is_absolute() else Path(rel)
            os.lchown(path, *owner)
    return Workspace(root, paths, colcon_root), created


GITIGNORE = ".gitignore"
GITIGNORE_TEMPLATE = """\
# colcon's outputs, espdock's builds' and yours: made again from the sources, never committed.
# espdock.toml, compose.yaml and the locks (rosdep.lock.json, ...) are sources: commit them.
{}/
{}/
{}/
"""


def unignored_outputs(root: Path, colcon_root: str) -> list[str] | None:
    """colcon's output directories, as .gitignore lines (/ws/build/), that git does not leave out
    of the repository ROOT is in: where a .gitignore was there already, init leaves it as it is,
    and a team's first `git add -A` committed build/, install/ and log/. Empty outside a git work
    tree (or without git); None where git refuses the repository as another user's."""
    outputs = posixpath.normpath(f"/{colcon_root}")
    lines = [posixpath.join(outputs, d) + "/" for d in ("build", "install", "log")]
    try:
        # One answer per path: source, line, pattern (a `!` one lets the path in again; none: no rule), path.
        asked = subprocess.run(
            ["git", "-C", str(root), "check-ignore", "--no-index", "--verbose", "--non-matching", "-z", "--stdin"],
            input="".join(line.lstrip("/") + "\0" for line in lines).encode(),
            capture_output=True,
            check=False,
        )
    except OSError:
        return []
    if asked.returncode not in (0, 1):
        # Not in a repository; or in one git will not read for this user (safe.directory).
        return None if b"dubious ownership" in asked.stderr else []
    patterns = asked.stdout.decode(errors="replace").split("\0")[2::4]
    return [
        _ignore_line(line)
        for line, pattern in zip(lines, patterns, strict=False)
        if not pattern or pattern.startswith("!")
    ]


def _ignore_line(path: str) -> str:
    """PATH (a directory's, ending in /) as a .gitignore line naming it literally: a colcon root
    `ws[1]` was a pattern there."""
    return re.sub(r"([\\*?\[])", r"\\\1", path)


GITATTRIBUTES = ".gitattributes"
# A Windows checkout (Git for Windows' core.autocrlf=true) gave every script a CRLF: a node
# script's `#!/usr/bin/env python3` ran `python3\r`, not found, and a shell step failed on `\r`.
GITATTRIBUTES_TEXT = """\
# What is here is built and run in Linux containers: every text file is checked out with LF,
# also on Windows (core.autocrlf), where a CRLF script fails there (`/usr/bin/env: 'python3\\r'`).
* text=auto eol=lf
"""


def _attributes_above(root: Path) -> bool:
    """Whether ROOT, or a directory above it within its git repository, has a .gitattributes
    (Git reads none above the repository's top)."""
    for directory in (root, *root.parents):
        if os.path.lexists(directory / GITATTRIBUTES):
            return True
        if os.path.lexists(directory / ".git"):
            return False
    return False


def undo_init(root: Path, created: list[str]) -> None:
    """Remove what init_workspace CREATED in ROOT, newest first (directories only while empty):
    an init that failed after it leaves the directory as it found it."""
    for rel in reversed(created):
        path = Path(rel) if Path(rel).is_absolute() else root / rel.rstrip("/")
        with contextlib.suppress(OSError):
            if path.is_dir() and not path.is_symlink():
                path.rmdir()
            else:
                path.unlink()
