"""`espdock colcon-extension install`: make espdock's colcon extension loadable by a colcon that
runs in another Python (apt's colcon with espdock from pipx, or a colcon venv of its own).

colcon-core finds extensions only as entry points of distributions in its own Python
(colcon_core.extension_point: importlib.metadata's entry_points(); COLCON_EXTENSION_BLOCKLIST can
only remove some). Without espdock's there, colcon-ros takes an esp_idf package.xml for a
`ros.esp_idf` package no task builds: `colcon build` warns and skips it, and exits 0. So this
writes, where that Python looks (its user site, or the venv's site-packages), a tiny distribution
whose entry points name a shim module; the shim puts espdock's own site-packages at the end of
sys.path (colcon's packages keep precedence) and has the extension run espdock with its own Python.
"""

from __future__ import annotations

import ast
import json
import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from espdock import __version__
from espdock.errors import ConfigError

SHIM = "espdock_colcon_shim"
DISTRIBUTION = "espdock_colcon_shim"
# The entry points of pyproject.toml's, pointing at the shim.
ENTRY_POINTS = (
    ("colcon_core.package_identification", "esp_idf", "EspIdfPackageIdentification"),
    ("colcon_core.task.build", "ros.esp_idf", "EspIdfBuildTask"),
    ("colcon_core.task.test", "ros.esp_idf", "EspIdfTestTask"),
)
# Asked of colcon's Python: where it reads distributions from, and whether espdock's extension is
# among them already (espdock installed beside colcon).
_PROBE = """
import json, os, site, sys, sysconfig
from importlib.metadata import entry_points
venv = sys.prefix != sys.base_prefix
where = sysconfig.get_paths()["purelib"] if venv else site.getusersitepackages()
eps = entry_points()
group = eps.select(group="colcon_core.task.build") if hasattr(eps, "select") else eps.get("colcon_core.task.build", [])
found, loaded = [], []
for e in group:
    if e.name == "ros.esp_idf":
        found.append(e.value)
        try:
            e.load()
        except Exception:
            continue
        # The Python the shim runs espdock with must be there too (a checkout's venv removed).
        runs = getattr(sys.modules.get("espdock.ros.colcon_extension"), "ESPDOCK_PYTHON", sys.executable)
        if os.access(runs, os.X_OK):
            loaded.append(e.value)
user_site = bool(site.ENABLE_USER_SITE)
print(json.dumps({"where": where, "found": found, "loaded": loaded, "user_site": user_site, "venv": venv}))
"""


@dataclass(frozen=True)
class ColconPython:
    """The Python a colcon executable runs in, and where it reads distributions from."""

    python: str
    site_dir: Path
    # Entry point values of espdock's build task it already sees (from a distribution not the shim's).
    found: tuple[str, ...]
    # Whether it loads espdock's extension at all (installed beside it, or through the shim).
    loads: bool = False


def colcon_python(colcon: str | None, env: dict[str, str]) -> ColconPython:
    """The Python of the colcon executable COLCON (default: `colcon` on PATH), read from its #! line."""
    path = shutil.which(colcon or "colcon", path=env.get("PATH"))
    if path is None:
        raise ConfigError(
            f"no colcon executable {colcon or 'colcon'!r} found on PATH",
            "Install colcon (e.g. `apt install python3-colcon-common-extensions`) or name it with --colcon PATH.",
        )
    with open(path, "rb") as handle:
        first = handle.readline().decode(errors="replace").strip()
    if not first.startswith("#!"):
        raise ConfigError(f"{path} does not start with a #! line naming its Python", "Name colcon's Python instead.")
    argv = first[2:].split()
    python = argv[1] if os.path.basename(argv[0]) == "env" and len(argv) > 1 else argv[0]
    # From /: Python puts the current directory first on its path, and a checkout's *.egg-info
    # there would pass for an installed distribution.
    result = subprocess.run([python, "-c", _PROBE], capture_output=True, text=True, check=False, env=env, cwd="/")
    if result.returncode != 0:
        raise ConfigError(f"colcon's Python {python} did not answer: {result.stderr.strip()[-500:]}")
    answer = json.loads(result.stdout)
    if not answer["venv"] and not answer["user_site"]:
        raise ConfigError(
            f"colcon's Python {python} reads no user site-packages (PYTHONNOUSERSITE?), so nothing can be added to it",
            "Install espdock into colcon's Python instead (`pip install` beside colcon).",
        )
    found = tuple(value for value in answer["found"] if not value.startswith(f"{SHIM}:"))
    # Declared is not loaded: a shim left pointing at a venv removed since (`pipx reinstall` with
    # another Python) fails to import espdock, and colcon skips the firmware all the same.
    return ColconPython(python, Path(answer["where"]), found, loads=bool(answer["loaded"]))


def colcon_skips_firmware(env: dict[str, str]) -> str | None:
    """What to tell a user whose `colcon` (on PATH) does not load espdock's extension: there
    `colcon build` skips every firmware package with only a warning, and exits 0. None when it
    loads it, or there is no colcon (or none this can ask)."""
    colcon = shutil.which("colcon", path=env.get("PATH"))
    if colcon is None:
        return None
    try:
        target = colcon_python(colcon, env)
    except ConfigError:
        return None
    shim = target.site_dir / f"{SHIM}.py"
    if target.loads:
        registered = _registered_site(shim)
        if registered is not None and Path(registered) != espdock_site():
            # A venv per checkout: colcon ran another checkout's espdock, and check said all was well.
            return (
                f"`colcon build` with {colcon} builds firmware packages through another espdock (the one in "
                f"{registered}), not this one ({espdock_site()}); `espdock colcon-extension install` registers "
                "this one"
            )
        return None
    if shim.is_file():
        return (
            f"`colcon build` with {colcon} skips firmware packages (a warning, exit code 0): espdock's extension "
            f"is registered in its Python ({target.python}) but cannot be loaded: the espdock it was registered "
            "from has moved or is gone; `espdock colcon-extension install` registers this one"
        )
    return (
        f"`colcon build` with {colcon} skips firmware packages (a warning, exit code 0): colcon loads "
        f"extensions only from its own Python ({target.python}), and espdock's is not there; "
        "`espdock colcon-extension install` registers it"
    )


def _registered_site(shim: Path) -> str | None:
    """The espdock site-packages the shim at SHIM loads espdock from (its ESPDOCK_SITE), or None."""
    try:
        text = shim.read_text()
    except OSError:
        return None
    found = re.search(r"^ESPDOCK_SITE = (.+)$", text, re.MULTILINE)
    try:
        return str(ast.literal_eval(found[1])) if found else None
    except (ValueError, SyntaxError):
        return None


def _shim_text(espdock_site: str, espdock_python: str) -> str:
    return (
        f'"""Written by `espdock colcon-extension install` (espdock {__version__}): espdock\'s colcon\n'
        "extension, loaded from the Python espdock is installed in. Remove with\n"
        '`espdock colcon-extension uninstall`."""\n\n'
        "import sys\n\n"
        f"ESPDOCK_SITE = {espdock_site!r}\n"
        "if ESPDOCK_SITE not in sys.path:\n"
        "    sys.path.append(ESPDOCK_SITE)  # last: colcon's own packages keep precedence\n\n"
        "from espdock.ros import colcon_extension as _extension  # noqa: E402\n\n"
        f"_extension.ESPDOCK_PYTHON = {espdock_python!r}\n"
        "EspIdfPackageIdentification = _extension.EspIdfPackageIdentification\n"
        "EspIdfBuildTask = _extension.EspIdfBuildTask\n"
        "EspIdfTestTask = _extension.EspIdfTestTask\n"
    )


def _dist_info(site_dir: Path) -> Path:
    return site_dir / f"{DISTRIBUTION}-{__version__}.dist-info"


def install_shim(target: ColconPython, espdock_site: Path, espdock_python: str) -> list[Path]:
    """Write the shim and its distribution into TARGET's site dir; return what was written."""
    uninstall_shim(target.site_dir)
    target.site_dir.mkdir(parents=True, exist_ok=True)
    module = target.site_dir / f"{SHIM}.py"
    module.write_text(_shim_text(str(espdock_site), espdock_python))
    info = _dist_info(target.site_dir)
    info.mkdir()
    (info / "METADATA").write_text(
        f"Metadata-Version: 2.1\nName: {DISTRIBUTION}\nVersion: {__version__}\n"
        "Summary: espdock's colcon extension, loaded from espdock's own Python\n"
    )
    groups: dict[str, list[str]] = {}
    for group, name, attribute in ENTRY_POINTS:
        groups.setdefault(group, []).append(f"{name} = {SHIM}:{attribute}")
    sections = (f"[{group}]\n" + "\n".join(lines) + "\n\n" for group, lines in groups.items())
    (info / "entry_points.txt").write_text("".join(sections))
    (info / "INSTALLER").write_text("espdock\n")
    written = [module, info / "METADATA", info / "entry_points.txt", info / "INSTALLER"]
    record = "".join(f"{p.relative_to(target.site_dir).as_posix()},,\n" for p in written)
    (info / "RECORD").write_text(record + f"{(info / 'RECORD').relative_to(target.site_dir).as_posix()},,\n")
    return [module, info]


def uninstall_shim(site_dir: Path) -> list[Path]:
    """Remove what install_shim wrote into SITE_DIR (any version); return what was removed."""
    removed = []
    for info in sorted(site_dir.glob(f"{DISTRIBUTION}-*.dist-info")):
        shutil.rmtree(info)
        removed.append(info)
    module = site_dir / f"{SHIM}.py"
    if module.exists():
        module.unlink()
        removed.append(module)
    return removed


def espdock_site() -> Path:
    """The site-packages directory espdock itself is imported from."""
    import espdock

    return Path(espdock.__file__).resolve().parent.parent


def espdock_python() -> str:
    return sys.executable
