"""`espdock colcon-extension install`'s files: what colcon's extension discovery (importlib.metadata
entry points of its Python's distributions) finds in the site dir they are written to."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

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
    said = " ".join(checked.stderr.split())
    assert f"`colcon build` with {colcon} skips firmware packages" in said, said
    assert "is registered in its Python (/usr/bin/python3) but cannot be loaded" in said, said


def test_check_fails_where_the_python_the_shim_runs_espdock_with_is_gone(tmp_path):
    """A checkout's venv removed: the shim loaded (espdock's site still there) and check passed,
    and every firmware build in colcon failed on FileNotFoundError for the Python it runs."""
    has_colcon = subprocess.run(["/usr/bin/python3", "-c", "import colcon_core"], capture_output=True, check=False)
    if has_colcon.returncode != 0:
        pytest.skip("Debian's colcon (python3-colcon-core) is not installed: `make test` installs it")
    colcon = tmp_path / "bin/colcon"
    colcon.parent.mkdir()
    colcon.write_text("#!/usr/bin/python3\n")
    colcon.chmod(0o755)
    env = {**os.environ, "PATH": f"{colcon.parent}:{os.environ['PATH']}", "PYTHONUSERBASE": str(tmp_path / "user")}
    site = subprocess.run(["/usr/bin/python3", "-m", "site", "--user-site"], env=env, capture_output=True,
                          text=True, check=True).stdout.strip()  # fmt: skip
    check = [sys.executable, "-m", "espdock", "colcon-extension", "check"]
    for runs, code in ((sys.executable, 0), (str(tmp_path / "removed-venv/bin/python"), 2)):
        install_shim(ColconPython("/usr/bin/python3", Path(site), ()), espdock_site(), runs)
        checked = subprocess.run(check, env=env, capture_output=True, text=True, check=False)
        assert checked.returncode == code, (runs, checked.stdout + checked.stderr)
    # Another checkout's espdock registered (a venv per checkout): it loads, and colcon runs that
    # one's firmware builds, where check passed.
    other = tmp_path / "other-checkout"
    other.mkdir()
    (other / "espdock").symlink_to(espdock_site() / "espdock")
    install_shim(ColconPython("/usr/bin/python3", Path(site), ()), other, sys.executable)
    checked = subprocess.run(check, env=env, capture_output=True, text=True, check=False)
    assert checked.returncode == 2, checked.stdout + checked.stderr
    said = " ".join(checked.stderr.split())
    assert f"builds firmware packages through another espdock (the one in {other}), not this one" in said, said
