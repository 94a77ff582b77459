"""What a runtime image takes from an install tree that colcon's --symlink-install made: links
into build/ and the sources, as the build containers wrote them (under /workspace), resolved."""

from __future__ import annotations

import os
from pathlib import Path

from espdock.ros.nodes import executables
from espdock.ros.runtime_tree import runtime_files, runtime_install_digest


def symlink_installed(root: Path) -> Path:
    """ROOT/ws as colcon --symlink-install leaves it for an ament_cmake and an ament_python package."""
    ws = root / "ws"
    (ws / "src/tools/scripts").mkdir(parents=True)
    (ws / "src/tools/scripts/banner").write_text("#!/bin/sh\necho banner\n")
    (ws / "src/tools/scripts/banner").chmod(0o755)
    (ws / "build/tools").mkdir(parents=True)
    (ws / "build/tools/report").write_bytes(b"\x7fELF compiled")
    (ws / "build/tools/report").chmod(0o755)
    lib = ws / "install/tools/lib/tools"
    lib.mkdir(parents=True)
    (lib / "report").symlink_to("/workspace/ws/build/tools/report")
    (lib / "banner").symlink_to("/workspace/ws/src/tools/scripts/banner")
    (lib / "libx.so").symlink_to("libx.so.1")  # an alias within the tree stays a link
    (lib / "libx.so.1").write_bytes(b"lib")
    # ament_python in develop mode: an egg-link to build/PKG, whose module is a link into src/.
    (ws / "src/talk/talk").mkdir(parents=True)
    (ws / "src/talk/talk/__init__.py").write_text("")
    (ws / "src/talk/talk/node.py").write_text("print('hello')\n")
    (ws / "build/talk/talk.egg-info").mkdir(parents=True)
    (ws / "build/talk/talk.egg-info/top_level.txt").write_text("talk\n")
    (ws / "build/talk/talk.egg-info/entry_points.txt").write_text("[console_scripts]\nnode = talk.node:main\n")
    (ws / "build/talk/talk").symlink_to("/workspace/ws/src/talk/talk")
    site = ws / "install/talk/lib/python3.11/site-packages"
    site.mkdir(parents=True)
    (site / "talk.egg-link").write_text("/workspace/ws/build/talk\n.")
    (ws / "install/talk/lib/talk").mkdir(parents=True)
    (ws / "install/talk/lib/talk/node").write_text("#!/opt/espdock/venv/bin/python3\n")
    (ws / "install/talk/lib/talk/node").chmod(0o755)
    (ws / "install/talk/share/talk").mkdir(parents=True)
    (ws / "install/talk/share/talk/package.dsv").write_text(
        "source;share/talk/hook/pythonpath.dsv\nsource;../../build/talk/share/talk/hook/pythonpath_develop.dsv\n"
    )
    (ws / "install/local_setup.sh").write_text("# colcon\n")
    return ws


def test_links_out_of_the_install_tree_are_taken_as_what_they_point_at(tmp_path):
    ws = symlink_installed(tmp_path)
    files = runtime_files(ws / "install", ("tools", "talk"), tmp_path)
    assert files["tools/lib/tools/report"] == ws / "build/tools/report"
    assert files["tools/lib/tools/banner"] == ws / "src/tools/scripts/banner"
    assert files["tools/lib/tools/libx.so"].is_symlink()
    site = "talk/lib/python3.11/site-packages"
    assert files[f"{site}/talk/node.py"] == ws / "src/talk/talk/node.py"
    assert files[f"{site}/talk.egg-info/entry_points.txt"] == ws / "build/talk/talk.egg-info/entry_points.txt"
    assert f"{site}/talk.egg-link" not in files
    # The develop hook names build/, which the image lacks (sourcing it fails with "not found").
    assert files["talk/share/talk/package.dsv"] == b"source;share/talk/hook/pythonpath.dsv\n"
    links = [path for path in files.values() if isinstance(path, Path) and path.is_symlink()]
    assert not [link for link in links if os.readlink(link).startswith("/")]
    # `espdock run` finds the linked executables, as `ros2 run` does in the build container.
    assert executables(ws / "install", "tools", tmp_path) == ["banner", "report"]


def test_an_edited_linked_source_changes_the_runtime_image_key(tmp_path):
    ws = symlink_installed(tmp_path)
    before = runtime_install_digest(ws / "install", ("tools", "talk"), tmp_path)
    (ws / "src/talk/talk/node.py").write_text("print('hello, edited')\n")
    assert runtime_install_digest(ws / "install", ("tools", "talk"), tmp_path) != before


def test_a_named_pipe_a_symlink_install_links_to_is_not_taken_nor_read(tmp_path):
    """A named pipe in a package's sources, which a symlink install links to: `espdock run` hung
    for good reading it for the runtime image's key (a socket: "a bug in espdock")."""
    import threading

    ws = symlink_installed(tmp_path)
    os.mkfifo(ws / "src/talk/talk/feed")
    keys: list[str] = []
    hashing = threading.Thread(
        target=lambda: keys.append(runtime_install_digest(ws / "install", ("tools", "talk"), tmp_path)), daemon=True
    )
    hashing.start()
    hashing.join(timeout=10)
    if hashing.is_alive():
        os.close(os.open(ws / "src/talk/talk/feed", os.O_WRONLY))  # lets the reading thread end
    assert keys, "hashing the install did not end"
    assert "talk/lib/python3.11/site-packages/talk/feed" not in runtime_files(ws / "install", ("talk",), tmp_path)


def test_an_editor_s_swap_and_backup_files_beside_a_linked_module_stay_out_of_the_image(tmp_path):
    """A symlink install's module directory is the sources: the runtime image `espdock compose`
    deploys held the editor's swap file, its backups and a .env beside the node, and each write of
    the swap file made a new image."""
    ws = symlink_installed(tmp_path)
    module = ws / "src/talk/talk"
    before = runtime_install_digest(ws / "install", ("tools", "talk"), tmp_path)
    for name in (".node.py.swp", "node.py~", ".env", "4913"):
        (module / name).write_text("secret=1\n")
    (module / ".mypy_cache").mkdir()
    (module / ".mypy_cache/x.json").write_text("{}")
    site = "talk/lib/python3.11/site-packages/talk"
    taken = {rel for rel in runtime_files(ws / "install", ("tools", "talk"), tmp_path) if rel.startswith(f"{site}/")}
    assert taken == {f"{site}/__init__.py", f"{site}/node.py"}
    assert runtime_install_digest(ws / "install", ("tools", "talk"), tmp_path) == before


def test_a_swap_file_an_ament_cmake_symlink_install_linked_stays_out_of_the_image(tmp_path):
    """ament_cmake's symlink install links each file of a directory it installs: the swap file and
    backup beside an ament_python_install_package module were in the runtime image, and each
    write of the swap file made a new one."""
    ws = symlink_installed(tmp_path)
    module = ws / "src/tools/tools_py"
    module.mkdir()
    installed = ws / "install/tools/local/lib/python3.11/dist-packages/tools_py"
    installed.mkdir(parents=True)
    for name in ("__init__.py", ".__init__.py.swp", "__init__.py~"):
        (module / name).write_text("swap1\n")
        (installed / name).symlink_to(f"/workspace/ws/src/tools/tools_py/{name}")
    before = runtime_install_digest(ws / "install", ("tools", "talk"), tmp_path)
    taken = {rel for rel in runtime_files(ws / "install", ("tools",), tmp_path) if "tools_py" in rel}
    assert taken == {"tools/local/lib/python3.11/dist-packages/tools_py/__init__.py"}
    (module / ".__init__.py.swp").write_text("swap2\n")
    assert runtime_install_digest(ws / "install", ("tools", "talk"), tmp_path) == before
