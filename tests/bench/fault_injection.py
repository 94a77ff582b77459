"""Fault-injection benchmark: SIGINT and SIGKILL of espdock at random moments of real builds.

Run: .venv/bin/python tests/bench/fault_injection.py [--interrupts 55] [--kills 22] [--seed N]

A workspace with custom_interface and led_strip_node (firmware built in the IDF contract
double, tests/idf_contract_double/, since espressif/idf cannot be pulled here) is built,
rebuilt uninterrupted (`build --force`: the reference install tree), then interrupted over
and over. Each round picks a phase and a signal, starts the command that runs that phase,
waits for the phase to start (its step's line in espdock's output), then sends the signal
after a random delay within the phase's duration (measured in the uninterrupted round):

  image      the micro-ROS image build (its image, unique to this run, removed first, and
             BuildKit's cache emptied: the library is built again)
  colcon     `build --force --only ros`, during colcon
  firmware   `build --force --only firmware`, during idf.py build
  install    the same, during the atomic install of the firmware
  manifest   the same, after the last step, while the manifest is hashed and written
  provision  `espdock provision` against esp32-mock-bootloader (real esptool)

After a SIGINT: exit code 130 within 10 s and no container of the workspace left. A signal
that lands after the command printed its last line (its work done, the process exiting) may
find it exiting 0: that is counted apart as "late", not as a failure; an exit 0 with output
after the signal is a failure (the signal went unanswered).
After a SIGKILL: the next `espdock build` removes what was left.
After either: the next `espdock build` succeeds and `espdock verify` finds its install tree
identical to the uninterrupted build's manifest.

Empties the engine's BuildKit cache before each image round. Only this run's workspaces'
containers are looked at (by the io.espdock.workspace label).
Prints the counts per phase and signal, the slowest exit, and every failure.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from espdock.build.steps import LABEL_WORKSPACE  # noqa: E402
from espdock.config import Config, resolve_ca_bundle  # noqa: E402
from espdock.images.engine import Engine  # noqa: E402
from tests.conftest import copy_workspace  # noqa: E402
from tests.idf_contract_double.build import use_double  # noqa: E402
from tests.ports import free_port  # noqa: E402

FIRMWARE = "led_strip_node"
CHIP = "esp32c3"  # led_strip_node's own (CONFIG_IDF_TARGET in its sdkconfig.defaults): the board emulated
EXIT_BUDGET = 10.0
ONLY_FIRMWARE = ("build", "--force", "--only", "firmware")
# phase: (command, the output line that starts it)
PHASES: dict[str, tuple[tuple[str, ...], str]] = {
    "image": (("build", "--only", "firmware"), "image espdock/idf-micro-ros"),
    "colcon": (("build", "--force", "--only", "ros"), "colcon build"),
    "firmware": (ONLY_FIRMWARE, f"idf.py build {FIRMWARE}"),
    "install": (ONLY_FIRMWARE, f"install {FIRMWARE}"),
    "manifest": (ONLY_FIRMWARE, f"✓ install {FIRMWARE}"),
    "provision": (("provision",), ""),
}


@dataclass
class Tally:
    sent: dict[tuple[str, str], int] = field(default_factory=dict)
    missed: int = 0
    late: dict[str, int] = field(default_factory=dict)  # per signal
    exits: list[tuple[float, str]] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)


def espdock_argv(args: tuple[str, ...], port: str) -> list[str]:
    if args == ("provision",):
        args = ("provision", FIRMWARE, "--port", port, "--wifi-ssid", "lab", "--wifi-password-file", "/dev/null",
                "--agent", "10.0.0.2:8888")  # fmt: skip
    return [sys.executable, "-m", "espdock", *args]


def run(root: Path, env: dict[str, str], *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "espdock", *args], cwd=root, env=env, capture_output=True,
                          text=True, check=False, timeout=1800)  # fmt: skip


class Watched:
    """An espdock process whose output lines are read as they come, each with its arrival time."""

    def __init__(self, argv: list[str], root: Path, env: dict[str, str]) -> None:
        self.process = subprocess.Popen(argv, cwd=root, env=env, stdout=subprocess.PIPE,
                                        stderr=subprocess.STDOUT, text=True)  # fmt: skip
        self.started = time.monotonic()
        self.lines: list[tuple[float, str]] = []
        self.seen = threading.Condition()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            with self.seen:
                self.lines.append((time.monotonic(), line.rstrip("\n")))
                self.seen.notify_all()
        with self.seen:
            self.seen.notify_all()

    def wait_for(self, prefix: str, timeout: float = 900) -> float | None:
        """When a line starting with PREFIX arrived; None if the process ended first."""
        deadline = time.monotonic() + timeout
        with self.seen:
            while True:
                for at, line in self.lines:
                    if line.strip().startswith(prefix):
                        return at
                if self.process.poll() is not None or time.monotonic() > deadline:
                    return None
                self.seen.wait(0.05)

    def quiet_since(self, moment: float) -> bool:
        """Whether every line the process printed had arrived by MOMENT (give or take the pipe)."""
        return not self.lines or self.lines[-1][0] <= moment + 0.1

    def output(self) -> str:
        return "\n".join(line for _, line in self.lines[-15:])


def fresh_image_build(micro_ros: str) -> None:
    """Make the next build of MICRO_ROS a real one: the image removed, and BuildKit's cache with
    it (else the cache answers every step in a second and there is no build to interrupt)."""
    subprocess.run(["docker", "rmi", micro_ros], capture_output=True, check=False)
    subprocess.run(["docker", "builder", "prune", "-af"], capture_output=True, check=False)


def phase_durations(report: dict, provision_seconds: float, manifest_seconds: float) -> dict[str, float]:
    steps = {s["step"]: s["seconds"] for s in report["steps"]}

    def step(prefix: str) -> float:
        return next(seconds for name, seconds in steps.items() if name.startswith(prefix))

    return {
        "image": max(step("image espdock/idf-micro-ros"), 1.0),
        "colcon": step("colcon build"),
        "firmware": step(f"idf.py build {FIRMWARE}"),
        "install": step(f"install {FIRMWARE}") + 0.05,
        "manifest": manifest_seconds,
        "provision": provision_seconds,
    }


class Bootloader:
    """esp32-mock-bootloader in the foreground, owned by this run (restarted after a fault)."""

    def __init__(self) -> None:
        self.process: subprocess.Popen | None = None
        self.url = ""
        self.start()

    def start(self) -> None:
        port = free_port()
        tool = Path(sys.executable).with_name("esp32-mock-bootloader")
        self.process = subprocess.Popen([str(tool), "run", "--chip", CHIP, "--port", str(port)],
                                        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            with socket.socket() as client:
                if client.connect_ex(("127.0.0.1", port)) == 0:
                    break
            time.sleep(0.1)
        self.url = f"socket://127.0.0.1:{port}"

    def ready(self) -> str:
        """The URL of a bootloader that answers: another test's `esp32-mock-bootloader stop` (which
        picks "the only running instance") may have stopped this one."""
        port = int(self.url.rsplit(":", 1)[1])
        with socket.socket() as client:
            if self.process is not None and self.process.poll() is None and client.connect_ex(("127.0.0.1", port)) == 0:
                return self.url
        self.restart()
        return self.url

    def restart(self) -> None:
        self.stop()
        self.start()

    def stop(self) -> None:
        if self.process is not None:
            self.process.kill()
            self.process.wait()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--interrupts", type=int, default=55)
    parser.add_argument("--kills", type=int, default=22)
    parser.add_argument("--seed", type=int, default=None)
    args = parser.parse_args()
    seed = args.seed if args.seed is not None else random.randrange(1 << 30)
    rng = random.Random(seed)
    engine = Engine.connect(os.environ)
    tally = Tally()
    bootloader = Bootloader()
    made_images: set[str] = set()
    began = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="espdock-faults-") as tmp:
        root = copy_workspace(Path(tmp) / "faulted")
        shutil.copy2(REPO / "Dockerfile.idf", root / "Dockerfile.idf")
        shutil.copytree(REPO / "firmware", root / "firmware")
        shutil.rmtree(root / "firmware/camera_node")
        # A comment unique to this run in an input of the micro-ROS image's key (led_strip_node uses
        # no workspace interface, so a .msg would not do): the image is this run's own to remove.
        recipe = root / "Dockerfile.idf"
        recipe.write_text(recipe.read_text() + f"# fault bench {uuid.uuid4().hex}\n")
        before = set(subprocess.run(["docker", "images", "-q", "--no-trunc"], capture_output=True, text=True,
                                    check=True).stdout.split())  # fmt: skip
        double = use_double(engine, resolve_ca_bundle(Config(), os.environ), lambda _: None, root)
        # A fixed SOURCE_DATE_EPOCH (the copy is no git checkout): .pyc files then do not carry build times.
        env = {**os.environ, **double, "SOURCE_DATE_EPOCH": "1700000000"}
        report = Path(tmp) / "report.json"
        expected = Path(tmp) / "expected-manifest.json"
        try:
            first = run(root, env, "build", "--report", str(report))
            if first.returncode != 0:
                sys.exit(f"the first build failed:\n{first.stdout[-3000:]}{first.stderr}")
            (micro_ros,) = [t for t in json.loads(report.read_text())["manifest"]["images"] if "micro-ros" in t]
            if engine.image(micro_ros) is None or engine.image(micro_ros).id in before:
                sys.exit(f"{micro_ros} existed before this run: refusing to remove an image it did not make")
            made_images.add(micro_ros)
            # Calibration, uninterrupted: how long each phase lasts here, now, and the install tree
            # every later build must match. (A rebuild, not the first build: setuptools' egg-info
            # SOURCES.txt lists more files on a rebuild than on a build from nothing.)
            fresh_image_build(micro_ros)
            calibrated = Watched(espdock_argv(("build", "--force", "--report", str(report)), ""), root, env)
            installed = calibrated.wait_for(PHASES["manifest"][1])
            calibrated.process.wait()
            manifest_seconds = time.monotonic() - (installed or 0.0)
            shutil.copy2(root / "ws/install/espdock-manifest.json", expected)
            started = time.monotonic()
            provisioned = run(root, env, *espdock_argv(("provision",), bootloader.ready())[3:])
            if calibrated.process.returncode != 0 or installed is None or provisioned.returncode != 0:
                failed = f"{calibrated.output()}\n{provisioned.stdout[-2000:]}\n{provisioned.stderr}"
                sys.exit(f"calibration failed:\n{failed}")
            durations = phase_durations(json.loads(report.read_text()), time.monotonic() - started, manifest_seconds)
            print(f"seed {seed}; phase durations (s): " + ", ".join(f"{k} {v:.2f}" for k, v in durations.items()))

            signals = ["SIGINT"] * args.interrupts + ["SIGKILL"] * args.kills
            rng.shuffle(signals)
            phases = list(PHASES)
            for number, name in enumerate(signals):
                phase = phases[number % len(phases)]
                one_round(
                    number, phase, name, root, env, engine, bootloader, micro_ros, expected, durations, rng, tally
                )
        finally:
            bootloader.stop()
            engine.remove_containers({LABEL_WORKSPACE: str(root)})
            subprocess.run(["docker", "rmi", *made_images], capture_output=True, check=False)

    print_summary(tally, time.monotonic() - began)


def one_round(number: int, phase: str, name: str, root: Path, env: dict[str, str], engine: Engine,
              bootloader: Bootloader, micro_ros: str, expected: Path, durations: dict[str, float],
              rng: random.Random, tally: Tally) -> None:  # fmt: skip
    label = f"#{number} {name} in {phase}"
    failed_before = len(tally.failures)
    command, trigger = PHASES[phase]
    if phase == "image":
        fresh_image_build(micro_ros)
    for attempt in range(4):
        port = bootloader.ready() if phase == "provision" else ""
        watched = Watched(espdock_argv(command, port), root, env)
        at = watched.wait_for(trigger) if trigger else watched.started
        # Each retry aims earlier; the last one signals as soon as the phase starts.
        delay = rng.uniform(0, durations[phase]) / (2**attempt) if attempt < 3 else 0.0
        if at is not None:
            time.sleep(max(0.0, at + delay - time.monotonic()))
        if at is None or watched.process.poll() is not None:
            tally.missed += 1  # it ended before the moment came: try again, earlier
            watched.process.wait()
            if phase == "image":
                fresh_image_build(micro_ros)
            continue
        sent = time.monotonic()
        watched.process.send_signal(signal.SIGINT if name == "SIGINT" else signal.SIGKILL)
        break
    else:
        tally.failures.append(f"{label}: the phase never ran long enough to be interrupted")
        return
    tally.sent[(phase, name)] = tally.sent.get((phase, name), 0) + 1
    try:
        code = watched.process.wait(timeout=60)
    except subprocess.TimeoutExpired:
        watched.process.kill()
        code = watched.process.wait()
        tally.failures.append(f"{label}: still running 60 s after the signal")
    took = time.monotonic() - sent
    if code == 0 and watched.quiet_since(sent):
        # The work was done and reported before the signal: exiting 0 is the truth.
        tally.late[name] = tally.late.get(name, 0) + 1
        label += " (late: the command had finished)"
    elif name == "SIGINT":
        tally.exits.append((took, label))
        left = engine.containers({LABEL_WORKSPACE: str(root)})
        if code != 130:
            tally.failures.append(f"{label}: exit code {code}, not 130:\n{watched.output()}")
        if took > EXIT_BUDGET:
            tally.failures.append(f"{label}: took {took:.1f} s to exit")
        if left:
            tally.failures.append(f"{label}: containers left after Ctrl-C: {left}")
    if phase == "provision":
        bootloader.restart()  # a flash write cut short leaves the mock mid-protocol
    after = run(root, env, "build")
    if after.returncode != 0:
        tally.failures.append(f"{label}: the next build failed ({after.returncode}):\n{after.stderr[-2000:]}")
        print(f"  FAILURE {tally.failures[-1]}", flush=True)
        return
    left = engine.containers({LABEL_WORKSPACE: str(root)})
    if left:
        tally.failures.append(f"{label}: containers left after the next build: {left}")
    verify = run(root, env, "verify", str(expected), "--install", str(root / "ws/install"))
    if verify.returncode != 0:
        tally.failures.append(f"{label}: the install tree differs from a clean build's:\n{verify.stdout[-2000:]}")
    print(f"{label}: exit {code} after {took:.2f} s; next build and verify "
          f"{'ok' if verify.returncode == 0 else 'FAILED'}", flush=True)  # fmt: skip
    for failure in tally.failures[failed_before:]:
        print(f"  FAILURE {failure}", flush=True)


def print_summary(tally: Tally, seconds: float) -> None:
    print(f"\nfault injection: {sum(tally.sent.values())} signals in {seconds / 60:.0f} min "
          f"({tally.missed} retried because the command ended before its moment; {sum(tally.late.values())} landed "
          f"after the command had printed its result and exited 0)")  # fmt: skip
    for signame in ("SIGINT", "SIGKILL"):
        per_phase = ", ".join(f"{phase} {tally.sent.get((phase, signame), 0)}" for phase in PHASES)
        total = sum(n for (_, s), n in tally.sent.items() if s == signame)
        late = tally.late.get(signame, 0)
        print(f"{signame:<8} {total:3d}, {total - late} during the work: {per_phase}")
    if tally.exits:
        slowest, where = max(tally.exits)
        typical = sorted(t for t, _ in tally.exits)[len(tally.exits) // 2]
        print(
            f"exit after SIGINT: median {typical:.2f} s, slowest {slowest:.2f} s ({where}); budget {EXIT_BUDGET:.0f} s"
        )
    print(f"failures: {len(tally.failures)}")
    for failure in tally.failures:
        print(f"  {failure}")


if __name__ == "__main__":
    main()
