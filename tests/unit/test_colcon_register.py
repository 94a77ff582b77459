"""`espdock colcon-extension install`'s files: what colcon's extension discovery (importlib.metadata
entry points of its Python's distributions) finds in the site dir they are written to."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from espdock.ros.colcon_register import ColconPython, espdock_site, install_shim, uninstall_shim

FIND = """
import json, sys
from importlib.metadata import entry_points
sys.path[:0] = [sys.argv[1]]
found = {}
for group in ("colcon_core.package_identification", "colcon_core.task.build"):
    for ep in entry_points(group=group):
        if ep.value.startswith("espdock_colcon_shim"):
            found[ep.name] = ep.load().__module__
print(json.dumps(found))
"""


def discovered(site: Path) -> dict[str, str]:
    """The shim's entry points a Python with SITE on its path finds, loaded (colcon's own way)."""
    result = subprocess.run([sys.executable, "-c", FIND, str(site)], capture_output=True, text=True, check=True)
    return json.loads(result.stdout)


def test_the_shim_registers_both_extensions_and_uninstall_removes_them(tmp_path):
    site = tmp_path / "site-packages"
    target = ColconPython(sys.executable, site, ())
    install_shim(target, espdock_site(), sys.executable)
    assert discovered(site) == {
        "esp_idf": "espdock.ros.colcon_extension",
        "ros.esp_idf": "espdock.ros.colcon_extension",
    }
    install_shim(target, espdock_site(), sys.executable)  # again: one copy, not two
    assert len(list(site.glob("espdock_colcon_shim-*.dist-info"))) == 1
    assert uninstall_shim(site)
    assert discovered(site) == {}


def test_check_fails_where_the_shim_no_longer_finds_espdock(tmp_path):
    """`pipx reinstall --python 3.12 espdock` moved espdock's site-packages: the shim colcon loads
    failed on "No module named 'espdock'", colcon skipped every firmware package and exited 0,
    and `espdock colcon-extension check` said colcon builds them (it only saw the shim declared)."""
    colcon = tmp_path / "bin/colcon"
    colcon.parent.mkdir()
    colcon.write_text("#!/usr/bin/python3\n")  # a colcon of the system's Python, as apt's
    colcon.chmod(0o755)
    env = {**os.environ, "PATH": f"{colcon.parent}:{os.environ['PATH']}", "PYTHONUSERBASE": str(tmp_path / "user")}
    site = subprocess.run(["/usr/bin/python3", "-m", "site", "--user-site"], env=env, capture_output=True,
                          text=True, check=True).stdout.strip()  # fmt: skip
    install_shim(ColconPython("/usr/bin/python3", Path(site), ()), tmp_path / "removed-venv/site-packages", "/nowhere")
    checked = subprocess.run([sys.executable, "-m", "espdock", "colcon-extension", "check"], env=env,
                             capture_output=True, text=True, check=False)  # fmt: skip
    assert checked.returncode == 2, checked.stdout + checked.stderr
    assert f"`colcon build` with {colcon} skips firmware packages" in " ".join(checked.stderr.split())
