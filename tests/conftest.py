"""Shared fixtures: the real Docker engine and throwaway copies of this workspace."""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path

import pytest

from espdock.build.steps import LABEL_INPUTS
from espdock.defaults import SHIPPED

pytest_plugins = ["tests.longest_first", "tests.engine_sweep"]
# The ROS packages the tests build carry tests of their own, which colcon runs in the images
# (`espdock test`), not this suite.
collect_ignore_glob = ["ros_packages/*"]

REPO = Path(__file__).resolve().parent.parent
IN_CI = os.environ.get("CI", "").lower() == "true"


@pytest.fixture(scope="session")
def engine():
    """The real engine, started if need be. In CI a missing engine fails; elsewhere it skips."""
    from espdock.errors import EspdockError
    from espdock.images import bootstrap

    try:
        engine = bootstrap.ensure_engine(os.environ, lambda text: None)
        bootstrap.ensure_compose(os.environ, lambda text: None)
    except EspdockError as exc:
        if IN_CI:
            pytest.fail(f"CI needs a Docker engine and none could be started: {exc.message}")
        pytest.skip(f"no Docker engine: {exc.message}")
    return engine


def copy_workspace(
    dest: Path,
    packages: tuple[str, ...] = ("custom_interface",),
    test_packages: tuple[str, ...] = (),
    runtime_image: bool = True,
) -> Path:
    """A fresh workspace at DEST holding this repo's image inputs, the named ws/src PACKAGES and the
    named tests/ros_packages TEST_PACKAGES. RUNTIME_IMAGE: keep the repo's setting that every
    build makes the runtime image (off, builds skip it: 3 s each where a test builds a dozen
    times and never runs it)."""
    dest.mkdir(parents=True, exist_ok=True)
    for name in ("espdock.toml", "Dockerfile.ros", ".dockerignore"):
        shutil.copy2(REPO / name, dest / name)
    # Not the demo's name: a test's runtime image must never replace espdock/demo:latest.
    dropped = ("name =",) if runtime_image else ("name =", "runtime_image =")
    config = dest / "espdock.toml"
    config.write_text("".join(line for line in config.read_text().splitlines(True) if not line.startswith(dropped)))
    shutil.copytree(REPO / "docker", dest / "docker")
    (dest / "ws" / "src").mkdir(parents=True)
    for package in packages:
        shutil.copytree(REPO / "ws" / "src" / package, dest / "ws" / "src" / package)
    for package in test_packages:
        shutil.copytree(REPO / "tests" / "ros_packages" / package, dest / "ws" / "src" / package)
    return dest


def message_package(dest: Path, name: str = "custom_interface", services: tuple[str, ...] = ()) -> Path:
    """This repository's custom_interface at DEST, named NAME, with its message and only the
    SERVICES named of its two: for tests of where a workspace's interfaces get built, installed
    and used, not of rosidl, which makes three more messages of each service (request, response
    and event) and takes about twice as long with both."""
    dropped = [f"srv/{srv}.srv" for srv in ("GetCameraConfig", "SetCameraConfig") if srv not in services]
    shutil.copytree(REPO / "ws/src/custom_interface", dest)
    for rel in dropped:
        (dest / rel).unlink()
    if not services:
        (dest / "srv").rmdir()
    cmake = dest / "CMakeLists.txt"
    cmake.write_text(
        "".join(line for line in cmake.read_text().splitlines(True) if line.strip().strip('"') not in dropped)
    )
    for path in (p for p in dest.rglob("*") if p.is_file()):
        path.write_text(path.read_text().replace("custom_interface", name))
    return dest


def python_workspace(dest: Path) -> Path:
    """A workspace at DEST whose only ROS package is beacon_nodes (ament_python).

    For tests about what happens around colcon (signals, faults, caches), not about what it
    compiles: it builds in a few seconds of CPU where the interface package's C and C++
    typesupport takes 15, and the suite is CPU-bound on two cores."""
    return copy_workspace(dest, packages=(), test_packages=("beacon_nodes",))


@pytest.fixture
def workspace(tmp_path: Path) -> Path:
    return copy_workspace(tmp_path / "ws-root")


def espdock(
    *args: str, cwd: Path, env: dict[str, str] | None = None, timeout: float = 900, prefix: tuple[str, ...] = ()
) -> subprocess.CompletedProcess[str]:
    """Run the espdock CLI as a user would (PREFIX: another command line for it), capturing its output.
    A Ctrl-C of the test run reaches espdock too (one process group): it is given the time its own
    clean-up takes. subprocess.run killed it 0.25 s later, and its build container stayed."""
    argv = [*(prefix or (sys.executable, "-m", "espdock")), *args]
    with subprocess.Popen(
        argv,
        cwd=cwd,
        env={**os.environ, **(env or {})},
        stdin=subprocess.DEVNULL,  # never the terminal pytest may run in: nothing may wait for typing
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        errors="replace",  # a non-UTF-8 locale's output (a Latin-1 ü) is read, not a crash of the test
    ) as process:
        try:
            stdout, stderr = process.communicate(timeout=timeout)
        except (subprocess.TimeoutExpired, KeyboardInterrupt):
            from espdock.interrupts import GRACE

            # Ended as Ctrl-C ends it, with its clean-up (a copy of the terminal's SIGINT at once
            # is one interruption to espdock): killed, its build container stayed.
            process.send_signal(signal.SIGINT)
            with contextlib.suppress(subprocess.TimeoutExpired):
                process.communicate(timeout=GRACE + 2)
            process.kill()
            process.communicate()
            raise
    return subprocess.CompletedProcess(argv, process.returncode, stdout, stderr)


def locale_env(tmp: Path, language: str, charmap: str) -> dict[str, str]:
    """The variables of a user whose locale is LANGUAGE in CHARMAP (en_US, ISO-8859-1): the locale
    made under TMP by localedef from the machine's locale sources (no root, no locale-gen)."""
    name = f"{language}.{charmap}"
    (tmp / "locales").mkdir(parents=True, exist_ok=True)
    made = subprocess.run(
        ["localedef", "-c", "-i", language, "-f", charmap, str(tmp / "locales" / name)],
        check=False,  # -c: warnings are no failure; the locale made is what counts
        capture_output=True,
        text=True,
    )
    assert (tmp / "locales" / name).is_dir(), made.stderr
    return {"LOCPATH": str(tmp / "locales"), "LC_ALL": name}


def ros_build_tag(root: Path) -> str:
    """The tag `espdock build` gives the ROS build image of the workspace at ROOT."""
    from espdock.config import load_config
    from espdock.ros.plan import ros_build_image
    from espdock.workspace import Workspace, read_build_inputs

    inputs = read_build_inputs(Workspace(root), ())
    return ros_build_image(load_config(root, {}), inputs.ros_dockerfile, inputs.ros_files).tag


def ros_runtime_tag(root: Path) -> str:
    """The tag of the runtime base image that goes with ros_build_tag(ROOT)."""
    from espdock.config import load_config
    from espdock.ros.plan import ros_build_image, runtime_base_image
    from espdock.workspace import Workspace, read_build_inputs

    inputs = read_build_inputs(Workspace(root), ())
    return runtime_base_image(ros_build_image(load_config(root, {}), inputs.ros_dockerfile, inputs.ros_files)).tag


def reader_exits_at(
    root: Path,
    text: str,
    *args: str,
    env: Mapping[str, str] | None = None,
    stderr_too: bool = False,
    timeout: float = 60,
) -> tuple[int, str]:
    """`espdock ARGS | grep -m1 TEXT` in ROOT (`2>&1 |` with STDERR_TOO): the reader closes the
    pipe at the first line with TEXT. espdock's exit code (within TIMEOUT s of that), and its
    stderr when kept apart."""
    process = subprocess.Popen(
        [sys.executable, "-m", "espdock", *args],
        cwd=root,
        env={**os.environ, **(env or {})},
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT if stderr_too else subprocess.PIPE,
        text=True,
    )
    try:
        assert process.stdout is not None
        next(line for line in process.stdout if text in line)
        process.stdout.close()
        code = process.wait(timeout=timeout)
        return code, process.stderr.read() if process.stderr else ""
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()


class Started:
    """`espdock ARGS` in the background as a user would start it (no terminal), its output
    (stdout and stderr) collected by line as it comes."""

    def __init__(self, root: Path, *args: str, env: dict[str, str] | None = None) -> None:
        self.process = subprocess.Popen(
            [sys.executable, "-m", "espdock", *args],
            cwd=root,
            env={**os.environ, **(env or {})},
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            self.lines.append(line.rstrip("\n"))

    def wait_for(self, text: str, timeout: float = 90) -> str:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            found = next((line for line in self.lines if text in line), None)
            if found:
                return found
            if self.process.poll() is not None and not self._reader.is_alive():
                break
            time.sleep(0.05)
        raise AssertionError(f"no line with {text!r} within {timeout:g} s; output:\n" + "\n".join(self.lines[-30:]))

    def interrupt(self, timeout: float = 30) -> int:
        self.process.send_signal(signal.SIGINT)
        code = self.process.wait(timeout=timeout)
        self._reader.join(timeout=5)
        return code

    def interrupt_timed(self) -> tuple[int, float]:
        """Send SIGINT, as `kill -INT` or a CI runner would; the exit code and how long the
        process took to end (it is killed after 60 s)."""
        sent = time.monotonic()
        self.process.send_signal(signal.SIGINT)
        try:
            code = self.process.wait(timeout=60)
        finally:
            took = time.monotonic() - sent
            self.stop()
        self._reader.join(timeout=5)
        return code, took

    def interrupt_on(self, text: str, timeout: float = 300) -> tuple[int, float]:
        """Once a line with TEXT came, interrupt_timed(); the process is stopped however this ends."""
        try:
            self.wait_for(text, timeout=timeout)
            return self.interrupt_timed()
        finally:
            self.stop()

    def output(self) -> str:
        return "\n".join(self.lines[-30:])

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()


def in_workspace_image(image: str, root: Path, *argv: str) -> subprocess.CompletedProcess[str]:
    """ARGV in IMAGE with the workspace ROOT at /workspace, as ROOT's owner: what a colcon build
    there left, seen as the build saw it."""
    stat = root.stat()
    return subprocess.run(
        ["docker", "run", "--rm", "-u", f"{stat.st_uid}:{stat.st_gid}", "-e", "HOME=/tmp",
         "-v", f"{root}:/workspace", "-w", "/workspace", image, *argv],
        capture_output=True, text=True, check=False, timeout=120,
    )  # fmt: skip


@contextmanager
def build_holding(root: Path, *command: str) -> Iterator[subprocess.Popen]:
    """Another process holding ROOT's workspace lock, as `espdock COMMAND` (default: build) does
    while it runs, until the block ends."""
    # COMMAND on its command line as well: a holder is named only while its process runs what it wrote.
    holder = (
        "import sys; from pathlib import Path; from espdock.workspace import Workspace, workspace_lock; "
        "sys.argv[0] = 'espdock';\n"
        f"with workspace_lock(Workspace(Path({str(root)!r}))):\n"
        "    print('locked', flush=True); sys.stdin.read()"
    )
    process = subprocess.Popen(
        [sys.executable, "-c", holder, *(command or ("build",))],
        cwd=REPO,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert process.stdout is not None and process.stdout.readline().strip() == "locked"
        yield process
    finally:
        # Its end, as a build's: the lock and the note of who holds it go (killed, the note stayed).
        process.communicate(timeout=30)


def leftover_containers(engine, root: Path) -> list[str]:
    return engine.containers({"io.espdock.workspace": str(root)})


def images_built_from(*dockerfiles: Path, untagged: bool = False) -> list[dict]:
    """The engine's inspect answers for the images built from one of DOCKERFILES as they are now
    (the file's sha256 in the image's recorded inputs); UNTAGGED: only those that lost every name."""
    wanted = {(path.name, hashlib.sha256(path.read_bytes()).hexdigest()) for path in dockerfiles}
    listing = ["docker", "image", "ls", "-q", "--no-trunc", "--filter", f"label={LABEL_INPUTS}"]
    listing += ["--filter", "dangling=true"] if untagged else []
    ids = sorted(set(subprocess.run(listing, capture_output=True, text=True, check=True).stdout.split()))
    if not ids:
        return []
    # An image removed meanwhile (another worker) is left out of the answer, which lists the others.
    inspect = subprocess.run(["docker", "image", "inspect", *ids], capture_output=True, text=True, check=False)
    made = []
    for image in json.loads(inspect.stdout or "[]"):
        try:
            inputs = json.loads(((image.get("Config") or {}).get("Labels") or {}).get(LABEL_INPUTS, "{}"))
        except ValueError:
            continue
        if wanted & set(inputs.items()):
            made.append(image)
    return made


def remove_images_built_from(*dockerfiles: Path) -> list[str]:
    """Remove every image built from one of DOCKERFILES as they are now, and say which names went.
    For tests that give their workspace a Dockerfile no other run has: its keyed images can never
    be reused, so they go with the test (the run's sweep keeps keyed images, which the next run
    would find)."""
    made = [tag for image in images_built_from(*dockerfiles) for tag in image.get("RepoTags") or ()]
    if made:
        subprocess.run(["docker", "rmi", "-f", *made], capture_output=True, check=False)
    return made


@pytest.fixture
def clean_containers(engine, workspace: Path) -> Iterator[None]:
    yield
    engine.remove_containers({"io.espdock.workspace": str(workspace)})


@pytest.fixture(scope="module")
def double(engine):
    """(image tag, micro-ROS commit) of the IDF contract double (tests/idf_contract_double), built
    once for each version of its files."""
    from espdock.config import Config, resolve_ca_bundle
    from tests.idf_contract_double.build import build_double

    return build_double(engine, resolve_ca_bundle(Config(), os.environ), lambda line: None)


@contextmanager
def containers_created(root: Path) -> Iterator[list[str]]:
    """IDs of the containers espdock creates for workspace ROOT while the block runs (the list is
    filled as it ends). From a `docker events` stream started before the block: the engine keeps
    only its last 256 events, which the other test workers' containers pass on a loaded engine
    within a long build, and a later query found no create of a container colcon had run in
    (or, asserting none was made, could not fail)."""
    filters = ("type=container", "event=create", f"label=io.espdock.workspace={root}")
    argv = ["docker", "events", "--since", f"{time.time() - 0.5:.3f}", "--format", "{{.ID}}"]
    argv += [arg for value in filters for arg in ("--filter", value)]
    created: list[str] = []
    with subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True) as stream:
        try:
            yield created
            time.sleep(1)  # the engine sends an event as it happens; the CLI prints it a moment later
        finally:
            stream.terminate()
            out, _ = stream.communicate(timeout=30)
    created += out.split()


def as_user(uid: int, gid: int, groups: list[int], espdock_bin: Path) -> tuple[str, ...]:
    group_arg = ",".join(map(str, groups)) if groups else None
    prefix = ["setpriv", f"--reuid={uid}", f"--regid={gid}"]
    prefix += [f"--groups={group_arg}"] if group_arg else ["--clear-groups"]
    return (*prefix, str(espdock_bin))


def user_env(home: Path) -> dict[str, str]:
    home.mkdir(exist_ok=True)
    return {"HOME": str(home), "PATH": os.environ["PATH"]}


def owners(root: Path) -> set[int]:
    found = set()
    for dirpath, dirnames, filenames in os.walk(root):
        for name in (*dirnames, *filenames):
            found.add(os.lstat(os.path.join(dirpath, name)).st_uid)
    return found


@pytest.fixture(scope="module")
def shared_dir():
    """A directory every test user can traverse (pytest's own tmp dir is root-only)."""
    path = Path(tempfile.mkdtemp(prefix="espdock-it-"))
    path.chmod(0o755)
    yield path
    shutil.rmtree(path, ignore_errors=True)


# What goes into espdock's wheel: the package and its build files, and the workspace
# defaults setup.py copies in.
WHEEL_INPUTS = ("pyproject.toml", "setup.py", "MANIFEST.in", "espdock", *SHIPPED)


def wheel_inputs_digest() -> str:
    """A digest of every file the wheel is made from."""
    digest = hashlib.sha256()
    for top in WHEEL_INPUTS:
        base = REPO / top
        files = [base] if base.is_file() else sorted(base.rglob("*"))
        for path in files:
            if path.is_file() and "__pycache__" not in path.parts:
                digest.update(f"{path.relative_to(REPO)}\0".encode() + path.read_bytes() + b"\0")
    return digest.hexdigest()[:16]


# Directories kept_in_temp handed to this process, each with a shared lock held until it exits.
_IN_USE: dict[Path, int] = {}


def shared_ros_images(engine, root: Path, *more: str) -> tuple[str, ...]:
    """MORE, and the ROS build and runtime images ROOT builds with, on the shared engine: built
    there when one is missing (it has a network; the engines the tests copy them into may not)."""
    images = (*more, ros_build_tag(root), ros_runtime_tag(root))
    if any(engine.image(tag) is None for tag in images):
        warm = espdock("build", "--only", "ros", cwd=root)
        assert warm.returncode == 0, warm.stdout + warm.stderr
    return images


def images_key(engine, images: Sequence[str], extra: str = "") -> str:
    """A digest of IMAGES' IDs on the shared engine (and EXTRA): what a kept copy of them is named by."""
    ids = "\0".join(f"{tag}={engine.image(tag).id}" for tag in images)
    return hashlib.sha256(f"{ids}{extra}".encode()).hexdigest()[:16]


def copy_images(images: Sequence[str], env: Mapping[str, str]) -> None:
    """IMAGES from the shared engine into the engine ENV's DOCKER_HOST names: docker save | docker load."""
    with subprocess.Popen(["docker", "save", *images], stdout=subprocess.PIPE) as save:
        loaded = subprocess.run(["docker", "load"], stdin=save.stdout, env=env, capture_output=True, check=False)
    assert save.returncode == 0 and loaded.returncode == 0, loaded.stderr


def kept_in_temp(name: str, key: str, make: Callable[[Path], None]) -> Path:
    """TMPDIR/NAME-KEY, a directory that outlives the run: made by MAKE (given the empty
    directory) unless a complete one is there, after removing any NAME-* of another KEY that no
    process uses. Made under a lock, so pytest workers and concurrent runs wait for one another;
    a directory handed out stays locked (shared) until the process exits, so another checkout's
    run with other inputs does not remove it mid-test."""
    tmp = Path(tempfile.gettempdir())
    place = tmp / f"{name}-{key}"
    with open(tmp / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (place / "complete").is_file():
            for old in tmp.glob(f"{name}-*"):
                if old.is_dir() and old != place and not _in_use_elsewhere(old):
                    shutil.rmtree(old, ignore_errors=True)
            shutil.rmtree(place, ignore_errors=True)  # an unfinished one: MAKE gets it empty
            place.mkdir()
            make(place)
            (place / "complete").touch()
        if place not in _IN_USE:
            _IN_USE[place] = os.open(place, os.O_RDONLY)
            fcntl.flock(_IN_USE[place], fcntl.LOCK_SH)
    return place


def _in_use_elsewhere(directory: Path) -> bool:
    """Whether a process (this one included, through another lock) holds DIRECTORY's shared lock."""
    fd = os.open(directory, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)  # releases the probe's own lock
    return False


@pytest.fixture(scope="session")
def wheel_espdock():
    """espdock from a wheel built out of this checkout, in a fresh venv outside the repository
    that any user can run (the repo's venv lives under root's home).

    Made once for each content of the wheel's inputs and kept in the temp dir, so the other
    pytest workers and the next run use the same one (building it and installing its
    dependencies takes about 20 s). The lock also keeps setuptools, which builds in the
    checkout (build/, *.egg-info), to one worker at a time."""

    def make(place: Path) -> None:
        place.chmod(0o755)
        dist = place / "dist"
        subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(dist), str(REPO)],
                       check=True, capture_output=True)  # fmt: skip
        (wheel,) = dist.glob("espdock-*.whl")
        subprocess.run(["/usr/bin/python3", "-m", "venv", str(place / "venv")], check=True)
        subprocess.run([str(place / "venv/bin/pip"), "install", "-q", str(wheel)], check=True, capture_output=True)

    return kept_in_temp("espdock-wheel", wheel_inputs_digest(), make) / "venv" / "bin" / "espdock"


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A test marked `engine` asks for the engine first, whichever fixtures it names: it skips with
    the reason where none answers (fails in CI), as docs/testing.md says; four failed there."""
    for item in items:
        names = getattr(item, "fixturenames", None)
        if item.get_closest_marker("engine") and names is not None and "engine" not in names:
            names.insert(0, "engine")
