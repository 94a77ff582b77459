"""The install listing a build stamp records beside it: its format is on disk in every workspace."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from espdock.build.stamps import StampFile, listing_digest, tree_state


def test_an_install_listing_keeps_the_format_earlier_builds_recorded(tmp_path):
    # A changed order or field would make every workspace's recorded listing stale: each
    # package rebuilt once after an upgrade, for nothing.
    root = tmp_path / "install"
    (root / "pkg" / "share").mkdir(parents=True)
    (root / "pkg" / "share" / "package.xml").write_text("<package/>")
    (root / "pkg" / "lib.so").write_bytes(b"\0" * 10)
    (root / "setup.sh").write_text("# colcon's, ignored\n")
    (root / "pkg.txt").write_text("x")
    (root / "linked").symlink_to("pkg")
    (root / "dangling").symlink_to("nowhere")

    def line(rel: str, target: str = "") -> str:
        info = os.lstat(root / rel)
        return f"{rel}\0{info.st_size}\0{info.st_mtime_ns}\0{target}\n"

    # Each directory's files and links by name, then its directories, depth first; links not followed.
    lines = [line("dangling", "nowhere"), line("linked", "pkg"), line("pkg.txt"), line("pkg/lib.so")]
    lines.append(line("pkg/share/package.xml"))
    expected = hashlib.sha256("".join(lines).encode()).hexdigest()
    assert listing_digest(root, ignore={"setup.sh"}) == expected
    assert listing_digest(tmp_path / "missing") is None


def test_output_dirs_are_left_out_only_where_they_are_outputs(tmp_path):
    """A Python subpackage `log` and an IDF project's components/log (an override of IDF's log
    component) are sources: a change in them was no change to the build, and the workspace
    volume never got them."""
    from espdock.build.stamps import source_files, tree_digest

    package = tmp_path / "ws/src/my_py"
    for rel in ("package.xml", "my_py/log/__init__.py", "components/log/log.c", "build/lib/x.py", "log/out.txt",
                "my_py/__pycache__/a.pyc", ".git/HEAD"):  # fmt: skip
        (package / rel).parent.mkdir(parents=True, exist_ok=True)
        (package / rel).write_text(rel)
    (tmp_path / "ws/build/my_py").mkdir(parents=True)
    (tmp_path / "ws/build/my_py/CMakeCache.txt").write_text("")
    found = {p.relative_to(package).as_posix() for p in source_files(package)}
    assert found == {"package.xml", "my_py/log/__init__.py", "components/log/log.c"}
    before = tree_digest(package)
    (package / "my_py/log/__init__.py").write_text('LEVEL = "v2"\n')
    assert tree_digest(package) != before
    # From the workspace root (the volume's sync): the colcon root's own outputs stay out too.
    every = {p.relative_to(tmp_path).as_posix() for p in source_files(tmp_path, (tmp_path, tmp_path / "ws"))}
    assert every == {f"ws/src/my_py/{rel}" for rel in found}


def test_a_file_name_that_is_not_utf_8_is_hashed_as_its_bytes(tmp_path):
    """A package file named caf\\xe9.txt made every build exit 70 ("a bug in espdock")."""
    from espdock.build.stamps import tree_digest

    (tmp_path / "package.xml").write_text("<package/>")
    odd = Path(os.fsdecode(bytes(tmp_path) + b"/caf\xe9.txt"))
    odd.write_text("a")
    before = tree_digest(tmp_path), listing_digest(tmp_path)
    odd.write_text("bb")
    assert tree_digest(tmp_path) != before[0] and listing_digest(tmp_path) != before[1]


def test_files_under_a_package_s_link_to_a_directory_are_its_sources(tmp_path):
    """`config -> ../../common/config` in a package (a config dir another repository holds): a
    file added there was no change, and the build kept installing the old config."""
    from espdock.build.stamps import source_files, tree_digest

    common = tmp_path / "common/config"
    common.mkdir(parents=True)
    (common / "robot.yaml").write_text("speed: 1\n")
    package = tmp_path / "src/bringup"
    package.mkdir(parents=True)
    (package / "package.xml").write_text("<package/>")
    (package / "config").symlink_to("../../common/config")
    (package / "loop").symlink_to(".")  # a link loop is walked once
    before = tree_digest(package)
    (common / "outside.yaml").write_text("speed: 2\n")
    assert tree_digest(package) != before
    # A link that leads nowhere is part of the package too: by its target's name (every build
    # crashed on it, exit 70).
    (package / "dangling").symlink_to("/nonexistent/x")
    dangling = tree_digest(package)
    (package / "dangling").unlink()
    (package / "dangling").symlink_to("/nonexistent/y")
    assert tree_digest(package) != dangling
    (package / "dangling").unlink()
    (package / "ping").symlink_to("pong")  # two links that lead to each other (ELOOP): the same
    (package / "pong").symlink_to("ping")
    assert tree_digest(package) not in (before, dangling)
    (package / "ping").unlink()
    (package / "pong").unlink()
    # The workspace volume's sync sends links as links: it does not follow them.
    assert {p.name for p in source_files(package)} == {"package.xml"}


def test_records_written_as_root_belong_to_the_workspace_s_build_dir_owner(tmp_path):
    """`sudo espdock build` in a user's workspace, failed or interrupted: the records it dropped
    before colcon ran were left root's, where only a build that succeeded handed them back."""
    from espdock.build.stamps import StampFile

    build = tmp_path / "build"
    build.mkdir()
    os.chown(build, 4242, 4243)
    stamps = StampFile(build / "stamps.json", 2)
    stamps.record({"talker": "s1", "listener": "s2"}, {"talker": "i1", "listener": "i2"})
    os.chown(stamps.path, 0, 0)  # as an espdock that handed nothing back left it
    stamps.forget(["talker"])  # as a build does before colcon runs
    assert (stamps.path.stat().st_uid, stamps.path.stat().st_gid) == (4242, 4243)


def test_a_listing_leaves_out_the_directories_it_is_told_to_as_well_as_files(tmp_path):
    """The workspace volume's record of install/ left out the firmware installs espdock adds on
    the host: the directories were walked all the same, so with a firmware package beside the ROS
    ones every build on the volume rebuilt every ROS package."""
    (tmp_path / "talker/share").mkdir(parents=True)
    (tmp_path / "talker/share/x").write_text("x")
    bare = listing_digest(tmp_path)
    (tmp_path / "board/share/board/firmware").mkdir(parents=True)
    (tmp_path / "board/share/board/firmware/app.bin").write_bytes(b"\0")
    (tmp_path / "espdock-manifest.json").write_text("{}")
    assert listing_digest(tmp_path, {"board", "espdock-manifest.json"}) == bare
    assert listing_digest(tmp_path, {"espdock-manifest.json"}) != bare


def test_a_named_pipe_or_a_socket_in_a_package_is_hashed_by_its_kind_without_being_read(tmp_path):
    """A build hashes its packages' files: it hung for good on a named pipe (waiting for a writer),
    and a socket failed it as "a bug in espdock". A changed kind is a change all the same."""
    import socket
    import threading

    package = tmp_path / "pkg"
    package.mkdir()
    (package / "package.xml").write_text("<package/>")
    os.mkfifo(package / "feed")
    server = socket.socket(socket.AF_UNIX)
    server.bind(str(package / "sock"))
    states = []
    try:
        hashing = threading.Thread(target=lambda: states.append(tree_state(package)), daemon=True)
        hashing.start()
        hashing.join(timeout=10)
        if hashing.is_alive():
            os.close(os.open(package / "feed", os.O_WRONLY))  # lets the reading thread end
        assert not hashing.is_alive() and states, "hashing the package did not end"
    finally:
        server.close()
    assert states[0].paths == ("feed", "package.xml", "sock")
    (package / "feed").unlink()
    (package / "feed").write_text("")
    assert tree_state(package).digest != states[0].digest


def test_an_editor_s_leftovers_and_save_files_are_no_sources(tmp_path):
    """A backup (`main.cpp~`, emacs' `#main.cpp#`), vim's `4913` or JetBrains' `___jb_tmp___` beside
    a source rebuilt the package, and removing the backup again built it afresh from scratch."""
    from espdock.build.stamps import tree_state

    package = tmp_path / "pkg"
    (package / "src").mkdir(parents=True)
    (package / "package.xml").write_text("<package/>")
    (package / "src/main.cpp").write_text("int main() {}\n")
    before = tree_state(package)
    for name in ("main.cpp~", "#main.cpp#", "4913", "main.cpp___jb_tmp___", "main.cpp___jb_old___", "main.cpp.orig"):
        (package / "src" / name).write_text("int main() { return 1; }\n")
    assert tree_state(package) == before
    (package / "src/4914.cpp").write_text("int f() { return 1; }\n")
    assert tree_state(package).digest != before.digest, "a source named by digits is a source"


def test_a_file_gone_between_the_listing_and_its_reading_is_not_a_crash(tmp_path, monkeypatch):
    """An editor's save makes and removes a temporary file: hashing a package while the user saved
    ended as "FileNotFoundError ...; this is a bug in espdock" (exit 70)."""
    from espdock.build import stamps

    package = tmp_path / "pkg"
    package.mkdir()
    (package / "package.xml").write_text("<package/>")
    listed = stamps.source_files
    monkeypatch.setattr(stamps, "source_files", lambda root, *a, **k: [*listed(root, *a, **k), root / "gone.tmp"])
    state = stamps.tree_state(package)
    monkeypatch.undo()
    assert state == stamps.tree_state(package)


def test_what_a_cmake_package_installs_is_declared_in_its_lists_and_modules_wherever_they_are(tmp_path):
    """A target renamed in a subdirectory's CMakeLists.txt (add_subdirectory) or a cmake/ module
    left what it had installed, and `espdock run` ran the old executable: only the top-level
    CMakeLists.txt counted as declaring what the package installs."""
    package = tmp_path / "src/tool"
    (package / "src").mkdir(parents=True)
    (package / "cmake").mkdir()
    files = {
        "CMakeLists.txt": "add_subdirectory(src)\n",
        "src/CMakeLists.txt": "add_executable(tool6 main.c)\n",
        "cmake/install.cmake": "install(TARGETS tool6)\n",
        "src/main.c": "int main(void) { return 0; }\n",
    }
    for rel, text in files.items():
        (package / rel).write_text(text)
    stamps = StampFile(tmp_path / "stamps.json")
    first = tree_state(package)
    stamps.record({"tool": "s1"}, {}, {"tool": "src/tool"}, {"tool": first})
    (package / "src/main.c").write_text("int main(void) { return 1; }\n")
    assert stamps.redeclared({"tool": tree_state(package)}) == (), "a source edit declares nothing new"
    for rel in ("src/CMakeLists.txt", "cmake/install.cmake"):
        (package / rel).write_text(files[rel].replace("tool6", "tool7"))
        assert stamps.redeclared({"tool": tree_state(package)}) == ("tool",), rel
        (package / rel).write_text(files[rel])
    # Built by an espdock that recorded no such digest for a CMake package: asked for, it counts.
    records = stamps.read()
    records["tool"]["declares"] = ""
    (tmp_path / "stamps.json").write_text(json.dumps(records))
    assert stamps.redeclared({"tool": tree_state(package)}) == ()
    assert stamps.redeclared({"tool": tree_state(package)}, unrecorded=True) == ("tool",)


def test_records_a_newer_espdock_wrote_are_told_from_an_older_one_s(tmp_path):
    """A teammate's espdock, upgraded first, rewrote the stamps: the build called them "an older
    espdock's"."""
    from espdock.build.stamps import StampFile

    path = tmp_path / "stamps.json"
    StampFile(path, 3).record({"new": "s1"}, {"new": None})
    StampFile(path, 1).record({"old": "s2"}, {"old": None})
    mine = StampFile(path, 2)
    assert set(mine.foreign(["new", "old"])) == {"new", "old"}
    assert mine.newer(["new", "old"]) == ("new",)


def test_a_file_read_before_in_the_same_command_is_read_again_once_it_changed(tmp_path, monkeypatch):
    """One command hashes a package's sources more than once (the build's stamps, then run's checks):
    the bytes of a file seen before are taken from what stat says of it, and must never hide an edit,
    one that keeps the size and puts the modification time back (`cp -p`, tar) included."""
    import os
    import time

    from espdock.build import stamps
    from espdock.build.stamps import tree_state

    # A file is remembered once its times are older than a clock tick or two: this one at once.
    monkeypatch.setattr(stamps, "_RACY_NS", 0)
    source = tmp_path / "pkg/node.py"
    source.parent.mkdir()
    source.write_text("print('one')\n")
    old = time.time_ns() - 10_000_000_000
    os.utime(source, ns=(old, old))
    time.sleep(0.01)
    first = tree_state(tmp_path / "pkg").digest
    assert tree_state(tmp_path / "pkg").digest == first
    with source.open("r+") as edit:  # in place: the same inode, the same size
        edit.write("print('two')\n")
    os.utime(source, ns=(old, old))
    assert tree_state(tmp_path / "pkg").digest != first


def test_the_digests_one_command_kept_never_hide_an_edit_from_the_next(tmp_path):
    """The digests of the files a command read are kept in the build dir for the next command (a
    no-op build read every byte of the workspace again): an edit that keeps the size and puts the
    modification time back (`cp -p`, tar) is still seen, and a broken file of them is no file."""
    import os
    import subprocess
    import sys
    import time

    from espdock.build.stamps import DIGESTS_FILE

    package = tmp_path / "src/pkg"
    package.mkdir(parents=True)
    source = package / "node.py"
    source.write_text("print('one')\n")
    (tmp_path / "build").mkdir()
    store = tmp_path / "build" / DIGESTS_FILE
    old = time.time_ns() - 10_000_000_000
    os.utime(source, ns=(old, old))
    command = (
        "import sys; from pathlib import Path; from espdock.build import stamps\n"
        "stamps._RACY_NS = 0  # remembered at once: the test's files are seconds old\n"
        f"stamps.keep_digests(Path({str(store)!r}))\n"
        f"print(stamps.tree_state(Path({str(package)!r})).digest); stamps.save_digests()"
    )

    def digest_in_a_new_process() -> str:
        ran = subprocess.run([sys.executable, "-c", command], capture_output=True, text=True, check=True)
        return ran.stdout.strip()

    first = digest_in_a_new_process()
    assert len(json.loads(store.read_text())["digests"]) == 1, "kept for the next command"
    assert digest_in_a_new_process() == first
    with source.open("r+") as edit:  # in place: the same inode, the same size, the time put back
        edit.write("print('two')\n")
    os.utime(source, ns=(old, old))
    edited = digest_in_a_new_process()
    assert edited != first and edited == tree_state(package).digest
    store.write_text('{"format": 1, "digests": {"1:2:3:4:5": "not hex"')  # cut short
    assert digest_in_a_new_process() == edited


def test_a_link_switched_between_stat_and_read_is_not_remembered_as_the_old_target(tmp_path, monkeypatch):
    """`ln -sfn` (a profile switched, a checkout) while espdock hashed: the old target's stat was kept
    with the new target's bytes, and builds said "up to date" after the link went back."""
    import os
    import time

    from espdock.build import stamps

    monkeypatch.setattr(stamps, "_RACY_NS", 0)
    old = time.time_ns() - 10_000_000_000
    for name, rate in (("a.yaml", "10"), ("b.yaml", "99")):
        (tmp_path / name).write_text(f"rate: {rate}\n")
        os.utime(tmp_path / name, ns=(old, old))
    link = tmp_path / "params.yaml"
    link.symlink_to("a.yaml")
    seen = link.stat()  # the walk's stat: a.yaml
    link.unlink()
    link.symlink_to("b.yaml")  # switched before the read
    assert stamps.content_sha256(link, seen) == hashlib.sha256(b"rate: 99\n").digest()
    link.unlink()
    link.symlink_to("a.yaml")
    assert stamps.content_sha256(link, link.stat()) == hashlib.sha256(b"rate: 10\n").digest()


def test_a_network_file_system_s_files_are_read_every_time(tmp_path, monkeypatch):
    """An NFS or sshfs client's stat may be its cached attributes for a minute after an edit made on
    another machine: nothing on such a file system is taken from what a stat says."""
    import os
    import time

    from espdock.build import stamps

    monkeypatch.setattr(stamps, "_RACY_NS", 0)
    source = tmp_path / "node.py"
    source.write_text("print('one')\n")
    old = time.time_ns() - 10_000_000_000
    os.utime(source, ns=(old, old))
    cached = source.stat()  # what the client still says after the edit below
    monkeypatch.setitem(stamps._filesystems, cached.st_dev, "nfs4")
    assert stamps.content_sha256(source, cached) == hashlib.sha256(b"print('one')\n").digest()
    source.write_text("print('two')\n")
    assert stamps.content_sha256(source, cached) == hashlib.sha256(b"print('two')\n").digest()
    monkeypatch.setitem(stamps._filesystems, cached.st_dev, "ext4")  # a local one's stat is its own
    stamps.content_sha256(source, source.stat())
    assert stamps._stat_key(source.stat()) in stamps._digests
