"""Build stamps: what a package was last built from, so a build where nothing changed starts nothing.

A stamp is a digest of everything that decides a package's build output: its source tree
(paths and bytes), the stamps of the workspace packages it depends on, the image it is
built in and colcon's settings for it. Next to it lies a digest of what the build installed (paths, sizes, modification
times), so a deleted or edited install tree is noticed too. Any difference, or no stamp, builds.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import re
import stat
import tempfile
import time
from collections.abc import Callable, Collection, Iterable, Mapping
from pathlib import Path
from typing import NamedTuple

from espdock import durable
from espdock.workspace import editor_leftover, walk_following_links

# Not sources: colcon's and IDF's outputs beside a package.xml (or in the colcon root), caches,
# VCS and editor state. Deeper down they are sources: a Python subpackage `log`, an IDF
# project's override of IDF's `log` component in components/log.
OUTPUT_DIRS = {"build", "install", "log", "managed_components"}


# sha256 of the files read, by what stat says of them: one command reads a package's sources, or
# the install tree, more than once (the build's stamps, then run's checks of what is stale; the
# runtime image's key, then the manifest), and every command read them all again, a robot's
# meshes hundreds of megabytes. Kept between commands in the colcon root's build dir
# (DIGESTS_FILE), as git's index keeps what it knows of a file: gone with the workspace, or with
# `rm -rf build`. A file changed within a tick of the clock keeps its times: one whose times are
# that recent when it is read is not remembered (git's "racily clean").
_RACY_NS = 2_000_000_000
DIGESTS_FILE = ".espdock-file-digests.json"
_KEPT = 50_000  # files of one workspace: 6 MB, read in 50 ms
_digests: dict[str, str] = {}  # "dev:ino:size:mtime_ns:ctime_ns" -> hex sha256
_used: set[str] = set()
_new: set[str] = set()
_store: dict[str, Path] = {}  # "file": where this workspace's digests are kept, once it is known
_loaded: set[Path] = set()  # the stores read into _digests: on the first file read, not at every start
_SHA256_HEX = re.compile(r"[0-9a-f]{64}")


def content_sha256(path: Path, info: os.stat_result) -> bytes:
    """The sha256 of the regular file PATH's bytes, INFO its stat()."""
    key = _stat_key(info)
    remembered = _local_filesystem(info.st_dev)
    if remembered and (store := _store.get("file")) is not None and store not in _loaded:
        _loaded.add(store)
        for known_key, digest in _stored(store).items():
            if isinstance(digest, str) and _SHA256_HEX.fullmatch(digest):
                _digests.setdefault(known_key, digest)
    if remembered and (known := _digests.get(key)) is not None:
        _used.add(key)
        return bytes.fromhex(known)
    with open(path, "rb") as opened:
        # What was read is the file INFO describes only where the open one is it: a link switched
        # between the caller's stat and the open (`ln -sfn`, a checkout) read another file.
        read = _stat_key(os.fstat(opened.fileno()))
        digest = hashlib.sha256(opened.read()).digest()
    if remembered and read == key and time.time_ns() - max(info.st_mtime_ns, info.st_ctime_ns) > _RACY_NS:
        _digests[key] = digest.hex()
        _used.add(key)
        _new.add(key)
    return digest


def _stat_key(info: os.stat_result) -> str:
    return f"{info.st_dev}:{info.st_ino}:{info.st_size}:{info.st_mtime_ns}:{info.st_ctime_ns}"


# File systems whose stat is the file's own: a network one's (NFS, SMB, sshfs and other FUSE, 9p)
# may be its client's cached attributes for a minute after an edit made elsewhere, which the open
# of a read used to refresh.
_LOCAL_FILESYSTEMS = {"ext2", "ext3", "ext4", "xfs", "btrfs", "tmpfs", "overlay", "zfs", "f2fs", "bcachefs", "jfs"}
_filesystems: dict[int, str] = {}


def _local_filesystem(device: int) -> bool:
    """Whether DEVICE (a stat's st_dev) holds a local file system (mountinfo's type for it)."""
    if not _filesystems:
        try:
            with open("/proc/self/mountinfo") as mounts:
                for line in mounts:
                    fields = line.split()
                    major, _, minor = fields[2].partition(":")
                    kind = fields[fields.index("-") + 1]
                    _filesystems.setdefault(os.makedev(int(major), int(minor)), kind)
        except (OSError, ValueError, IndexError):
            _filesystems[-1] = ""  # no mountinfo (not Linux): remember nothing
    return _filesystems.get(device, "") in _LOCAL_FILESYSTEMS


def keep_digests(store: Path) -> None:
    """Take the digests earlier commands in this workspace kept in STORE (read when a file is first
    hashed: `espdock list` reads none), and keep this one's there (save_digests)."""
    _store["file"] = store


def _stored(store: Path) -> dict[str, str]:
    try:
        if not store.is_file():  # a named pipe there would hold every command
            return {}
        data = json.loads(store.read_text())
        found = data["digests"] if data.get("format") == 1 else {}
        return found if isinstance(found, dict) else {}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):  # none yet, or half written
        return {}


def save_digests() -> None:
    """Keep the digests of what this command read for the next (another's, meanwhile, merged): those
    of files it did not read go first when there are too many. Best effort: a lost cache costs a read."""
    store = _store.get("file")
    if store is None or not _new or not store.parent.is_dir():  # no build dir: nothing was built here
        return
    merged = {**_stored(store), **_digests}
    ordered = [k for k in merged if k not in _used] + [k for k in merged if k in _used]
    kept = {key: merged[key] for key in ordered[-_KEPT:]}
    with contextlib.suppress(OSError):
        fd, temporary = tempfile.mkstemp(prefix=f".{store.name}.", dir=store.parent)
        try:
            if os.geteuid() == 0:  # `sudo espdock`: the workspace's files stay its owner's
                owner = store.parent.stat()
                os.fchown(fd, owner.st_uid, owner.st_gid)
            os.fchmod(fd, 0o644)
            with os.fdopen(fd, "w") as out:
                json.dump({"format": 1, "digests": kept}, out, separators=(",", ":"))
            os.replace(temporary, store)
        except BaseException:
            os.unlink(temporary)
            raise
    _new.clear()


def tree_digest(*roots: Path) -> str:
    """sha256 over every file under ROOTS (relative path and content), hidden and output dirs skipped."""
    return tree_state(*roots)[0]


class TreeState(NamedTuple):
    """A package's sources as a build saw them (tree_state)."""

    digest: str  # tree_digest
    newest: int  # the newest modification time (ns) of a file
    paths: tuple[str, ...]  # the files, each relative to its root
    # The digest of the files declaring what a package installs (declaring(); "" without them):
    # setup.py's entry points and data_files, CMake's targets and install rules, and so what
    # stays installed when they stop.
    declares: str


# The files of a package (relative to it) that declare what setuptools installs.
SETUP_FILES = ("setup.py", "setup.cfg")


def declaring(rel: str) -> bool:
    """Whether the file REL (relative to its package) declares what the package installs:
    setuptools' SETUP_FILES, and CMake's lists and modules wherever they are (add_subdirectory)."""
    return rel in SETUP_FILES or rel.rpartition("/")[2] == "CMakeLists.txt" or rel.endswith(".cmake")


# A record's setup.py digest after a build that failed with another: matches no tree_state.
CHANGED_SINCE = "changed by a build that did not finish"


def tree_state(*roots: Path) -> TreeState:
    """tree_digest of ROOTS, the newest modification time of a file in them, their files' paths
    and the digest of the files declaring what they install."""
    digest = hashlib.sha256()
    declares = hashlib.sha256()
    newest = 0
    paths: list[str] = []
    for root in roots:
        # File names are bytes: one that is not UTF-8 (Python's lone surrogates) is hashed as it is.
        digest.update(f"root\0{root.name}\n".encode(errors="surrogateescape"))
        for path in source_files(root, follow_links=True):
            rel = path.relative_to(root).as_posix()
            try:
                info = path.stat()
                newest = max(newest, info.st_mtime_ns)
                # A named pipe would hang the build reading it, a socket fail it: such a file is
                # hashed by its kind, as no build reads it.
                special = not stat.S_ISREG(info.st_mode)
                if special:
                    content = hashlib.sha256(b"not a regular file\0%o" % stat.S_IFMT(info.st_mode)).digest()
                else:
                    content = content_sha256(path, info)
                # `chmod +x` on a node script is an edit: copying installs (install(DIRECTORY
                # USE_SOURCE_PERMISSIONS), setuptools' data_files) take the mode from the source.
                executable = not special and bool(info.st_mode & stat.S_IXUSR)
            except OSError as exc:
                if exc.errno == errno.ENOENT and not os.path.lexists(path):
                    # Gone since the walk listed it: an editor's temporary file of a save
                    # (vim's 4913, JetBrains' ___jb_tmp___), which the build will not see either.
                    continue
                # A link that leads nowhere, or around in a loop (ELOOP): its target's name.
                if not path.is_symlink() or exc.errno not in (errno.ENOENT, errno.ELOOP):
                    raise
                content = hashlib.sha256(b"dangling link\0" + os.fsencode(os.readlink(path))).digest()
                executable = False
            paths.append(rel)
            digest.update(rel.encode(errors="surrogateescape") + b"\0")
            digest.update(content)
            if executable:
                digest.update(b"\0executable")
            if declaring(rel):
                declares.update(rel.encode() + b"\0" + content)
    declared = declares.hexdigest() if any(declaring(p) for p in paths) else ""
    return TreeState(digest.hexdigest(), newest, tuple(paths), declared)


def listing_digest(root: Path, ignore: Collection[str] = ()) -> str | None:
    """sha256 over paths, sizes and modification times under ROOT (symlinks as their targets'
    names, not followed) but for the files and directories IGNORE names directly in ROOT; None
    when ROOT does not exist. Cheap: reads no file contents, and stats each entry once (every
    build and test checks the whole install tree this way)."""
    if not root.exists() and not root.is_symlink():
        return None
    digest = hashlib.sha256()
    # Depth first, each directory's entries by name, as os.walk with sorted names gives them:
    # the digests recorded by earlier espdock versions stay valid.
    pending = [("", os.fspath(root))]
    while pending:
        prefix, directory = pending.pop()
        try:
            with os.scandir(directory) as scan:
                entries = sorted(scan, key=lambda entry: entry.name)
        except OSError:
            continue
        subdirs = []
        for entry in entries:
            if not prefix and entry.name in ignore:
                continue
            try:
                linked = entry.is_symlink()
                if not linked and entry.is_dir():
                    subdirs.append((prefix + entry.name + "/", entry.path))
                    continue
                info = entry.stat(follow_symlinks=False)
                target = os.readlink(entry.path) if linked else ""
            except OSError:
                continue
            line = f"{prefix}{entry.name}\0{info.st_size}\0{info.st_mtime_ns}\0{target}\n"
            digest.update(line.encode(errors="surrogateescape"))
        pending.extend(reversed(subdirs))
    return digest.hexdigest()


def package_stamps(
    sources: Mapping[str, str],
    depends: Mapping[str, Iterable[str]],
    image: str | Mapping[str, str],
    settings: Mapping[str, str] | None = None,
    reads: Mapping[str, Iterable[str]] | None = None,
) -> dict[str, str]:
    """Each package's stamp from its source digest, its workspace dependencies' stamps, IMAGE (or
    the package's, by name) and its colcon SETTINGS digest (options, colcon.meta, defaults files:
    espdock.ros.colcon).

    SOURCES must list the packages in dependency order (a package after what it depends on).
    A dependency's stamp is part of its dependents', so a change rebuilds what depends on it.
    READS: for a package whose own build reads fewer of its DEPENDS (an ament_python package's
    exec_depends), those: its stamp carries only theirs, while what builds on it carries all of
    them (colcon's environment for that build holds what the package runs with).
    """
    whole: dict[str, str] = {}
    stamps: dict[str, str] = {}
    for name, source in sources.items():
        setting = (settings or {}).get(name, "")
        held = image if isinstance(image, str) else image[name]
        own = f"{held}\0{name}\0{source}\0{setting}\n"
        whole[name] = _chained(own, depends.get(name, ()), whole)
        stamps[name] = _chained(own, reads[name], whole) if reads is not None and name in reads else whole[name]
    return stamps


def _chained(own: str, deps: Iterable[str], stamps: Mapping[str, str]) -> str:
    digest = hashlib.sha256(own.encode())
    for dep in sorted(set(deps) & stamps.keys()):
        digest.update(f"{dep}\0{stamps[dep]}\n".encode())
    return digest.hexdigest()


class StampFile:
    """A JSON file of {package: {"stamp": ..., "installed": ...}} under ws/build.

    With a FORMAT, each record says the format it was written in, and a record of another
    format (an older espdock's, or one a colleague's older espdock rewrote) is stale: what it
    holds does not say what this espdock checks (where a package was built from, whether it was
    built on a dependency's old install), so its package is built again, afresh."""

    def __init__(self, path: Path, format: int | None = None) -> None:
        self.path = path
        self.format = format

    def read(self) -> dict[str, dict[str, str | None]]:
        try:
            data = json.loads(self.path.read_text())
        except (OSError, ValueError):
            return {}
        return data if isinstance(data, dict) else {}

    def up_to_date(self, stamps: Mapping[str, str], installed: Mapping[str, str | None]) -> bool:
        """True when every package's stamp and install listing are those recorded."""
        return not self.stale(stamps, installed)

    def stale(
        self, stamps: Mapping[str, str], installed: Mapping[str, str | None], sources: Mapping[str, str] | None = None
    ) -> tuple[str, ...]:
        """The packages of STAMPS (in their order) whose stamp or install listing is not the one
        recorded: what changed, and through the chained stamps, what depends on it; with
        SOURCES (name -> its directory), what moved as well."""
        recorded = self.read()
        moved = _moved(recorded, sources or {})
        return tuple(
            name
            for name, stamp in stamps.items()
            if not (
                self._current(recorded.get(name))
                and stamp in (recorded[name].get("stamp"), recorded[name].get("serves"))
                and installed.get(name) is not None
                and recorded[name].get("installed") == installed[name]
                and name not in moved
            )
        )

    def _current(self, entry: object) -> bool:
        return isinstance(entry, dict) and (self.format is None or entry.get("format") == self.format)

    def moved(self, sources: Mapping[str, str]) -> dict[str, str]:
        """The packages of SOURCES (name -> its directory) last built from another directory: that one."""
        return _moved(self.read(), sources)

    def put_back(self, trees: Mapping[str, TreeState]) -> tuple[str, ...]:
        """The packages of TREES (name -> its tree_state now) whose sources changed since their last
        build with no file newer than the newest then: put back from a backup or an archive
        (`cp -p`, `git archive | tar -x`), or a file renamed or removed. make and setuptools,
        which decide by time, would keep what the build made of the sources before."""
        return self._where(
            trees,
            lambda entry, now: (
                isinstance(entry.get("newest"), int)
                and entry.get("tree") not in (None, now.digest)
                and now.newest <= entry["newest"]
            ),
        )

    def removed(self, trees: Mapping[str, TreeState]) -> dict[str, tuple[str, ...]]:
        """The packages of TREES (name -> its tree_state now) that lost source files since their last
        build (a branch checked out, a file renamed): those files, an editor's leftovers aside. colcon
        builds on the install prefix, and what they installed (a module, a config, a script) stayed
        installed, and in the runtime image, whatever else changed beside."""
        recorded = self.read()
        lost = {}
        for name, now in trees.items():
            entry = recorded.get(name)
            before = entry.get("paths") if isinstance(entry, dict) else None
            if isinstance(before, list) and (gone := sorted(set(before) - set(now.paths))):
                if gone := tuple(path for path in gone if isinstance(path, str) and not editor_leftover(path)):
                    lost[name] = gone
        return lost

    def gained(self, trees: Mapping[str, TreeState]) -> tuple[str, ...]:
        """The packages of TREES that have source files their last build did not (a branch switched
        back): a CMake build that lists its sources with file(GLOB) keeps the list it was configured with."""
        return self._where(
            trees,
            lambda entry, now: isinstance(before := entry.get("paths"), list) and bool(set(now.paths) - set(before)),
        )

    def unlisted(self, trees: Mapping[str, TreeState]) -> tuple[str, ...]:
        """The packages of TREES whose sources changed since a build an older espdock recorded, which
        kept no list of their files: whether one was lost is not known."""
        return self._where(
            trees, lambda entry, now: entry.get("tree") not in (None, now.digest) and "paths" not in entry
        )

    def redeclared(self, trees: Mapping[str, TreeState], unrecorded: bool = False) -> tuple[str, ...]:
        """The packages of TREES whose declaring files (declaring()) changed since their last build:
        an entry point or a data file taken out of setup.py stayed installed (`espdock run` listed
        the script, and it failed), since setuptools only adds to an install; as did a CMake target
        renamed or an install rule taken out (the old executable ran). UNRECORDED: and those whose
        record has none of their digest (an older espdock's, of a CMake package)."""

        def holds(entry: dict, now: TreeState) -> bool:
            before = entry.get("declares")
            return before != now.declares if before else unrecorded and bool(now.declares)

        return self._where(trees, holds)

    def reconfigured(self, settings: Mapping[str, str]) -> tuple[str, ...]:
        """The packages of SETTINGS (name -> the digest of its colcon options and settings files now)
        whose last build recorded other ones (not those an older espdock built, which kept none)."""
        recorded = self.read()
        return tuple(
            name
            for name, now in settings.items()
            if isinstance(entry := recorded.get(name), dict) and entry.get("settings") not in (None, now)
        )

    def install_changed(self, installed: Mapping[str, str | None]) -> tuple[str, ...]:
        """The packages of INSTALLED (name -> listing_digest of its install prefix now) whose last
        build finished and left another listing there: changed since by something else (a file put
        there or edited by hand, a build of the user's own); not one that is gone."""
        recorded = self.read()
        return tuple(
            name
            for name, now in installed.items()
            if now is not None
            and self._current(entry := recorded.get(name))
            and "stamp" in entry
            and entry.get("installed") not in (None, now)
        )

    def _where(self, trees: Mapping[str, TreeState], holds: Callable[[dict, TreeState], bool]) -> tuple[str, ...]:
        """The packages of TREES whose record and tree_state now HOLDS is true of."""
        recorded = self.read()
        return tuple(
            name for name, now in trees.items() if isinstance(entry := recorded.get(name), dict) and holds(entry, now)
        )

    def foreign(self, names: Iterable[str]) -> tuple[str, ...]:
        """NAMES whose records are of another format than this file's."""
        recorded = self.read()
        return tuple(name for name in names if name in recorded and not self._current(recorded[name]))

    def newer(self, names: Iterable[str]) -> tuple[str, ...]:
        """NAMES whose records a newer espdock wrote (a higher format than this one's)."""
        recorded = self.read()

        def format_of(entry: object) -> int:
            value = entry.get("format") if isinstance(entry, dict) else None
            return value if isinstance(value, int) else 0

        return tuple(name for name in names if self.format is not None and format_of(recorded.get(name)) > self.format)

    def record(
        self,
        stamps: Mapping[str, str],
        installed: Mapping[str, str | None],
        sources: Mapping[str, str] | None = None,
        trees: Mapping[str, TreeState] | None = None,
        serves: Mapping[str, str] | None = None,
        against: Mapping[str, Mapping[str, str]] | None = None,
        outside: Mapping[str, Mapping[str, str]] | None = None,
        settings: Mapping[str, str] | None = None,
    ) -> None:
        """Record STAMPS with what is installed now (and each package's directory, from SOURCES,
        and its own sources' state, from TREES: tree_state), keeping other
        packages' records. SERVES: another stamp each package's build stands for as well (a test
        build's install is the one a plain build of the same sources would make). AGAINST: the
        stamps of the packages each was built on, as they were (what `espdock run` compares).
        OUTSIDE: the files of the workspace outside its directory each one's build read, with
        their contents' digests. SETTINGS: the digest of each one's colcon options and settings
        files (what reconfigured() compares)."""
        data = self.read()
        for name, stamp in stamps.items():
            data[name] = self._entry(name, sources, stamp=stamp, installed=installed.get(name))
            if serves and name in serves:
                data[name]["serves"] = serves[name]
            if against and name in against:
                data[name]["against"] = dict(against[name])  # type: ignore[assignment]
            if outside is not None and name in outside:
                data[name]["outside"] = dict(outside[name])  # type: ignore[assignment]
            if settings and name in settings:
                data[name]["settings"] = settings[name]
            if trees and name in trees:
                now = trees[name]
                state = {"tree": now.digest, "newest": now.newest, "paths": list(now.paths), "declares": now.declares}
                data[name].update(state)  # type: ignore[arg-type]
        self._write(data)

    def list_outside(self, outside: Mapping[str, Mapping[str, str]]) -> None:
        """Give the records of OUTSIDE's packages (kept as they are otherwise) what each one's
        build read of the workspace outside its directory (espdock.ros.cmake_inputs)."""
        data = self.read()
        for name, read in outside.items():
            if isinstance(data.get(name), dict):
                data[name]["outside"] = dict(read)  # type: ignore[assignment]
        self._write(data)

    def _write(self, data: Mapping[str, object]) -> None:
        """DATA as the file, which (written as root: `sudo espdock build`) takes the owner of its
        directory, the workspace's build/: a build that failed or was interrupted, which never got
        to hand its records back, left them root's."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        durable.write_text(self.path, json.dumps(data, indent=1, sort_keys=True) + "\n")
        if os.geteuid() == 0:
            directory = self.path.parent.stat()
            os.chown(self.path, directory.st_uid, directory.st_gid)

    def _entry(self, name: str, sources: Mapping[str, str] | None, **fields: str | None) -> dict[str, str | None]:
        entry = dict(fields)
        if sources and name in sources:
            entry["source"] = sources[name]
        if self.format is not None:
            entry["format"] = self.format  # type: ignore[assignment]
        return entry

    def forget(
        self,
        names: Iterable[str],
        sources: Mapping[str, str] | None = None,
        trees: Mapping[str, TreeState] | None = None,
    ) -> None:
        """Drop NAMES' records (their build failed or was interrupted: build them next time). With
        SOURCES, what is about to build from there keeps only that directory: a build dir colcon
        configures there is one of that directory, however the build ends. With TREES (their
        tree_state now), each keeps the files of both its last build and this one, and a setup.py
        digest that matches neither where this one's differs: a build that fails after a branch
        switch has installed some of the new files beside the old ones, and the next build must
        still see what went, whichever branch it is on."""
        before = self.read()
        data = dict(before)
        for name in names:
            if sources and name in sources:
                entry = before.get(name) if isinstance(before.get(name), dict) else {}
                kept = {k: entry[k] for k in ("paths", "declares") if k in entry}
                if trees and name in trees:
                    now = trees[name]
                    kept["paths"] = sorted({*kept.get("paths", ()), *now.paths})
                    if kept.get("declares", now.declares) != now.declares:
                        kept["declares"] = CHANGED_SINCE
                data[name] = {**self._entry(name, sources), **kept}
            else:
                data.pop(name, None)
        if data != before:
            self._write(data)

    def restore(self, records: Mapping[str, dict[str, str | None]], forgotten: Iterable[str] = ()) -> None:
        """Put back RECORDS that forget dropped, and drop what it kept of the other FORGOTTEN: the
        run that was to rebuild them changed nothing."""
        before, dropped = self.read(), set(forgotten) - set(records)
        data = {name: entry for name, entry in before.items() if name not in dropped} | dict(records)
        if data == before:
            return
        if data:
            self._write(data)
        else:
            self.path.unlink(missing_ok=True)  # as it was before a first build that never started


def _moved(recorded: Mapping[str, object], sources: Mapping[str, str]) -> dict[str, str]:
    return {
        name: old
        for name, rel in sources.items()
        if isinstance(entry := recorded.get(name), dict) and (old := entry.get("source")) not in (None, rel)
    }


def source_files(root: Path, output_parents: Collection[Path] = (), follow_links: bool = False) -> list[Path]:
    """The files under ROOT a build reads: hidden files and dirs, __pycache__, .pyc and editors'
    leftovers (editor_leftover) left out, and OUTPUT_DIRS where they are outputs: in a package's
    directory (it holds a package.xml), and in OUTPUT_PARENTS (the colcon root). FOLLOW_LINKS:
    under links to directories as well, each directory once (a package's `config ->
    ../../common/config`, which colcon installs)."""
    found = []
    parents = {os.fspath(p) for p in output_parents}
    for dirpath, dirnames, filenames in walk_following_links(root) if follow_links else os.walk(root):
        outputs = "package.xml" in filenames or dirpath in parents
        dirnames[:] = sorted(
            d for d in dirnames if not d.startswith(".") and d != "__pycache__" and not (outputs and d in OUTPUT_DIRS)
        )
        found += [
            Path(dirpath) / f
            for f in sorted(filenames)
            if not f.startswith(".") and not f.endswith(".pyc") and not editor_leftover(f)
        ]
    return found
