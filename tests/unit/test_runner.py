"""The runner against FakeEngine: cache hits and misses, colcon failures, no-op builds, events."""

from __future__ import annotations

import json
import os
import tempfile
import threading
import time
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path

import pytest

from espdock.build.runner import Runner
from espdock.build.steps import EnsureImage, Plan
from espdock.config import Config
from espdock.errors import BuildFailed, ConfigError, RegistryError
from espdock.events import Outcome, StepFinished, StepNote
from espdock.firmware.plan import IdfBuild, InstallFirmware
from espdock.images import bootstrap, machine_lock
from espdock.images.keyed import DPKG_STATUS
from espdock.images.specs import ImageInfo, RegistryStatus, registry_answer
from espdock.ros.nodes import check_built_by_espdock
from espdock.ros.plan import ColconBuild, ros_build_image
from espdock.workspace import Workspace
from tests.conftest import build_holding
from tests.fake_engine import FakeEngine

DOCKERFILE = "ARG BASE_IMAGE=debian:bookworm-slim\nFROM ${BASE_IMAGE} AS build\n"
SPEC = ros_build_image(Config(), DOCKERFILE, {})


@pytest.fixture
def ws(tmp_path, monkeypatch) -> Workspace:
    monkeypatch.setattr(bootstrap, "ensure_compose", lambda env, notify: None)
    for name in ("msgs", "app"):
        (tmp_path / "ws/src" / name).mkdir(parents=True)
        (tmp_path / "ws/src" / name / "package.xml").write_text(f"<package><name>{name}</name></package>\n")
    return Workspace(tmp_path)


def runner(engine: FakeEngine, events: list) -> Runner:
    return Runner(engine, Config(), {}, events.append, (os.getuid(), os.getgid()))  # type: ignore[arg-type]


COLCON = ColconBuild(image=SPEC.tag, packages=("msgs", "app"), sources=(("msgs", "src/msgs"), ("app", "src/app")),
                     depends=(("msgs", ()), ("app", ("msgs",))))  # fmt: skip


def colcon_installs(ws: Workspace, code: int = 0, lines: tuple[str, ...] = (), rcs: dict | None = None):
    """Plays `colcon build` of msgs and app: what it installs and the log/latest_build/events.log
    colcon-output writes ('[time] (job) EventClass: {members}'), honouring --packages-select.
    RCS: a package's return code (colcon-core's 'SIGINT' when aborted, None when skipped);
    the others get CODE."""

    def named(argv: list[str], option: str) -> tuple[str, ...]:
        if option not in argv:
            return ()
        rest = argv[argv.index(option) + 1 :]
        return tuple(rest[: next((i for i, a in enumerate(rest) if a.startswith("-")), len(rest))])

    def play(spec, on_line):
        for line in lines:
            on_line(line)
        argv = list(spec.argv)
        # --packages-ignore: as if colcon had not found it, so no event names it.
        paths = named(argv, "--base-paths")
        found = tuple(
            n
            for n in ("msgs", "app")
            if n not in named(argv, "--packages-ignore") and (not paths or any(p.endswith(f"/{n}") for p in paths))
        )
        selected = tuple(n for n in found if n not in named(argv, "--packages-skip"))
        if "--packages-select" in argv:
            selected = tuple(n for n in selected if n in named(argv, "--packages-select"))
        log = (
            ws.ws_dir
            / "log"
            / f"build_{len(list((ws.ws_dir / 'log').glob('build_*'))) if (ws.ws_dir / 'log').is_dir() else 0}"
        )
        log.mkdir(parents=True)
        events = [f"[0.000100] (-) JobUnselected: {{'identifier': '{n}'}}" for n in found if n not in selected]
        for name in selected:
            events.append(f"[0.000200] ({name}) JobQueued: {{'identifier': '{name}', 'dependencies': OrderedDict()}}")
        for name in selected:
            rc = (rcs or {}).get(name, code)
            if rc is None:
                events.append(f"[0.900000] ({name}) JobSkipped: {{'identifier': '{name}'}}")
                continue
            events.append(f"[0.300000] ({name}) JobStarted: {{'identifier': '{name}'}}")
            if rc == 0:
                (ws.ws_dir / "install" / name).mkdir(parents=True, exist_ok=True)
                (ws.ws_dir / "install" / name / "marker").write_text(f"{name} {log.name}")
            else:
                (log / name).mkdir()
                (log / name / "stdout_stderr.log").write_text(f"{name} failed\n")
            events.append(f"[0.800000] ({name}) JobEnded: {{'identifier': '{name}', 'rc': {rc!r}}}")
        (log / "events.log").write_text("\n".join(events) + "\n")
        latest = ws.ws_dir / "log" / "latest_build"
        latest.unlink(missing_ok=True)
        latest.symlink_to(log.name)
        return code

    return play


def test_an_image_with_the_key_is_a_cache_hit_and_nothing_is_built(ws):
    engine = FakeEngine({SPEC.tag: ImageInfo("id", (SPEC.tag,), datetime.now(UTC), 1, SPEC.labels())})
    events: list = []
    runner(engine, events).run(Plan(ws, (EnsureImage(SPEC),)))
    assert engine.builds == []
    assert any(isinstance(e, StepNote) and "cache hit" in e.text for e in events)
    assert events[-1] == StepFinished("image espdock/ros-jazzy-build", Outcome.CACHED, events[-1].seconds, SPEC.tag)


def test_a_tag_whose_label_is_another_key_is_rebuilt(ws):
    stale = ImageInfo("id", (SPEC.tag,), datetime.now(UTC), 1, {"io.espdock.key": "something else"})
    engine = FakeEngine({SPEC.tag: stale})
    events: list = []
    runner(engine, events).run(Plan(ws, (EnsureImage(SPEC),)))
    assert [b["tag"] for b in engine.builds] == [SPEC.tag]
    assert engine.builds[0]["labels"]["io.espdock.key"] == SPEC.key
    assert events[-1].outcome is Outcome.BUILT


def test_a_missing_base_image_is_made_only_when_an_image_must_be_built_from_it(ws, monkeypatch):
    """An air-gapped lab whose `debian:bookworm-slim` tag was cleaned up: a build whose keyed
    images were all present stopped at "pulling debian:bookworm-slim", then debootstrap."""
    from espdock.build.preview import preview
    from espdock.build.steps import EnsureBaseImage

    base = dict(SPEC.build_args)["BASE_IMAGE"]
    made: list[str] = []

    def make(engine, ref, config, notify):
        made.append(ref)
        engine.images_by_tag[ref] = ImageInfo("base", (ref,), datetime.now(UTC), 1, {})
        return "debootstrap"

    monkeypatch.setattr(bootstrap, "_make_base_image", make)
    plan = Plan(ws, (EnsureBaseImage(base), EnsureImage(SPEC)))
    engine = FakeEngine({SPEC.tag: ImageInfo("id", (SPEC.tag,), datetime.now(UTC), 1, SPEC.labels())})
    assert (
        preview(ws, plan, engine, registry=False)[0] == "not here, and not needed: the images built from it are present"
    )
    events: list = []
    runner(engine, events).run(plan)
    assert made == [] and engine.builds == []
    assert base not in engine.images_by_tag
    finished = [e for e in events if isinstance(e, StepFinished)]
    assert [(e.step, e.outcome, e.detail) for e in finished] == [
        (f"base image {base}", Outcome.CACHED, "not here, and not needed: the images built from it are present"),
        ("image espdock/ros-jazzy-build", Outcome.CACHED, SPEC.tag),
    ]

    engine.images_by_tag.clear()  # a cache miss: the base is made, then the image built from it
    assert preview(ws, plan, engine, registry=False)[0] == "would be pulled, else built with debootstrap"
    # The official ROS image is never debootstrapped (the build stops, saying to load it): nor said to be.
    official = Plan(ws, (EnsureBaseImage(base, debootstrap=False), EnsureImage(SPEC)))
    assert preview(ws, official, engine, registry=False)[0] == "would be pulled (nothing builds it)"
    events = []
    runner(engine, events).run(plan)
    assert made == [base] and [b["tag"] for b in engine.builds] == [SPEC.tag]
    # The base step made it, and says so (a --report's CI reader sees it).
    assert next((e.step, e.outcome, e.detail) for e in events if isinstance(e, StepFinished)) == (
        f"base image {base}",
        Outcome.BUILT,
        "debootstrap",
    )


def test_a_failed_package_is_named_with_its_log_and_the_next_build_tries_again(ws):
    failing = colcon_installs(ws, code=2, lines=("Starting >>> msgs", "Failed   <<< msgs [0.4s, exited with code 2]"))
    engine = FakeEngine(run_script=failing)
    events: list = []
    with pytest.raises(BuildFailed) as err:
        runner(engine, events).run(Plan(ws, (COLCON,)))
    assert "msgs" in err.value.message
    assert str(ws.ws_dir / "log/latest_build/msgs/stdout_stderr.log") in err.value.message
    assert events[-1].outcome is Outcome.FAILED
    engine.run_script = colcon_installs(ws)
    runner(engine, []).run(Plan(ws, (COLCON,)))
    assert len(engine.runs) == 2


def test_a_failure_names_the_packages_the_build_then_did_not_build(ws):
    """Each firmware package is a step after colcon's: the summary ended at the failure, and
    nothing said which of them were left unbuilt."""
    engine = FakeEngine(run_script=colcon_installs(ws, code=2))
    later = (IdfBuild("cam_fw", "src/cam_fw", "i", "esp32", "k"), InstallFirmware("cam_fw", "src/cam_fw", ()),
             IdfBuild("led_fw", "src/led_fw", "i", "esp32c3", "k"))  # fmt: skip
    with pytest.raises(BuildFailed) as err:
        runner(engine, []).run(Plan(ws, (COLCON, *later)))
    assert err.value.hint.endswith("Not built, the build having stopped here: cam_fw, led_fw.")
    engine.run_script = colcon_installs(ws, code=2)
    with pytest.raises(BuildFailed) as err:
        runner(engine, []).run(Plan(ws, (COLCON,)))
    assert "Not built" not in (err.value.hint or "")


def test_a_build_where_nothing_changed_runs_no_container(ws):
    engine = FakeEngine(run_script=colcon_installs(ws))
    runner(engine, []).run(Plan(ws, (COLCON,)))
    events: list = []
    runner(engine, events).run(Plan(ws, (COLCON,)))
    assert len(engine.runs) == 1
    assert events[-1].outcome is Outcome.CACHED and "up to date" in events[-1].detail
    # A dependency's change rebuilds; so does a removed install tree; so does --force.
    ((ws.root / "ws/src") / "msgs/msg.txt").write_text("x")
    runner(engine, []).run(Plan(ws, (COLCON,)))
    assert len(engine.runs) == 2
    (ws.ws_dir / "install/app/marker").unlink()
    runner(engine, []).run(Plan(ws, (COLCON,)))
    assert len(engine.runs) == 3
    from dataclasses import replace

    runner(engine, []).run(Plan(ws, (replace(COLCON, force=True),)))
    assert len(engine.runs) == 4


def test_a_firmware_source_saved_while_idf_py_builds_is_built_by_the_next_build(ws):
    """An editor's save after idf.py read the file: the stamp was taken after the build, so it
    held the edit, and the next build said "up to date (esp32)" of firmware without it; `espdock
    flash` wrote that firmware to the board."""
    project = ws.root / "fw/cam_fw"
    (project / "main").mkdir(parents=True)
    (project / "package.xml").write_text("<package><name>cam_fw</name></package>\n")
    (project / "main/main.c").write_text("void app_main(void) {}\n")
    step = IdfBuild("cam_fw", "fw/cam_fw", "i", "esp32", "k")

    def idf_py(spec, on_line):
        (project / "dependencies.lock").write_text("version: 2.0.0\n")  # idf.py's own, at each build
        if saving:
            (project / "main/main.c").write_text("void app_main(void) { int edited = 1; }\n")
        return 0

    saving = True
    engine = FakeEngine(run_script=idf_py)
    runner(engine, events := []).run(Plan(ws, (step,)))
    assert "main/main.c changed while idf.py built cam_fw" in notes(events)
    saving = False
    runner(engine, events := []).run(Plan(ws, (step,)))
    assert len(engine.runs) == 2, "the edit was taken for built"
    assert events[-1].outcome is Outcome.BUILT and "changed while" not in notes(events)
    runner(engine, events := []).run(Plan(ws, (step,)))
    assert len(engine.runs) == 2 and "up to date" in events[-1].detail, "idf.py's own lock is no edit"


def test_a_first_firmware_build_naming_a_component_from_elsewhere_is_no_edit_during_it(ws):
    """The build's project_description.json names a component outside the project (another
    EXTRA_COMPONENT_DIRS entry): read only after the first build, its files were taken for ones
    saved during it, and the firmware was built again for nothing."""
    project = ws.root / "fw/cam_fw"
    (project / "main").mkdir(parents=True)
    (project / "package.xml").write_text("<package><name>cam_fw</name></package>\n")
    shared = ws.root / "shared/blink"
    shared.mkdir(parents=True)
    (shared / "blink.c").write_text("void blink(void) {}\n")
    step = IdfBuild("cam_fw", "fw/cam_fw", "i", "esp32", "k")

    def idf_py(spec, on_line):
        build_dir = ws.ws_dir / "build/cam_fw"
        build_dir.mkdir(parents=True, exist_ok=True)
        paths = ["/workspace/fw/cam_fw/main", "/workspace/shared/blink"]
        (build_dir / "project_description.json").write_text(json.dumps({"build_component_paths": paths}))
        return 0

    engine = FakeEngine(run_script=idf_py)
    runner(engine, events := []).run(Plan(ws, (step,)))
    assert "changed while" not in notes(events)
    runner(engine, events := []).run(Plan(ws, (step,)))
    assert len(engine.runs) == 1 and "up to date" in events[-1].detail


def test_the_colcon_container_runs_as_the_owner_in_the_colcon_root(ws):
    engine = FakeEngine(run_script=colcon_installs(ws))
    runner(engine, []).run(Plan(ws, (COLCON,)))
    (spec,) = engine.runs
    assert spec.user == f"{os.getuid()}:{os.getgid()}"
    assert [(m.source, m.target) for m in spec.mounts] == [(ws.root, "/workspace")]
    assert spec.workdir == "/workspace/ws"
    assert engine.removed == [{"io.espdock.workspace": str(Path(ws.root)), "io.espdock.step": "colcon"}]


REGISTRY = "registry.example.com/team"
REMOTE = f"{REGISTRY}/{SPEC.tag}"


def cache_runner(engine: FakeEngine, events: list, push: bool = False) -> Runner:
    config = Config(cache_registry=REGISTRY)
    return Runner(engine, config, {}, events.append, (os.getuid(), os.getgid()), push_cache=push)  # type: ignore[arg-type]


def notes(events: list) -> str:
    return "\n".join(e.text for e in events if isinstance(e, StepNote))


def test_an_image_the_cache_registry_does_not_serve_is_neither_pulled_nor_pushed(ws):
    """A workspace's runtime image, one small layer over the keyed runtime base (which is served):
    looked up in the cache registry before each build of it, and pushed, where the docs said it
    is not (a registry that does not answer held each runtime image build up, and failed --push-cache)."""
    engine = FakeEngine(registry={REMOTE: ImageInfo("id", (REMOTE,), datetime.now(UTC), 1, SPEC.labels())})
    events: list = []
    (result,) = cache_runner(engine, events, push=True).run(Plan(ws, (EnsureImage(SPEC, cached=False),)))
    assert result.outcome is Outcome.BUILT and engine.pushed == []
    assert "cache registry" not in notes(events)


def test_a_miss_pulls_the_keyed_image_from_the_cache_registry_instead_of_building(ws):
    engine = FakeEngine(registry={REMOTE: ImageInfo("id", (REMOTE,), datetime.now(UTC), 1, SPEC.labels())})
    events: list = []
    (result,) = cache_runner(engine, events).run(Plan(ws, (EnsureImage(SPEC),)))
    assert result.outcome is Outcome.PULLED
    assert engine.builds == [] and SPEC.tag in engine.images_by_tag and REMOTE not in engine.images_by_tag
    assert "pulled from the cache registry" in notes(events)


def test_a_pulled_image_with_another_key_label_is_rejected_and_built_here(ws):
    wrong = ImageInfo("id", (REMOTE,), datetime.now(UTC), 1, {"io.espdock.key": "0" * 64})
    engine = FakeEngine(registry={REMOTE: wrong})
    events: list = []
    (result,) = cache_runner(engine, events).run(Plan(ws, (EnsureImage(SPEC),)))
    assert result.outcome is Outcome.BUILT and len(engine.builds) == 1
    assert "rejected" in notes(events) and engine.images_by_tag[SPEC.tag].labels["io.espdock.key"] == SPEC.key


def test_push_cache_replaces_an_image_under_the_key_that_this_run_rejected(ws):
    """The rejected image stayed in the registry ("already in the cache registry"): every later run pulled
    it, rejected it and built the image again."""
    wrong = ImageInfo("id", (REMOTE,), datetime.now(UTC), 1, {"io.espdock.key": "0" * 64})
    engine = FakeEngine(registry={REMOTE: wrong})
    events: list = []
    (result,) = cache_runner(engine, events, push=True).run(Plan(ws, (EnsureImage(SPEC),)))
    assert result.outcome is Outcome.BUILT and engine.pushed == [REMOTE]
    assert engine.registry[REMOTE].labels["io.espdock.key"] == SPEC.key
    assert "replacing the image it held" in notes(events)
    engine.untag(SPEC.tag)  # the next machine
    (again,) = cache_runner(engine, []).run(Plan(ws, (EnsureImage(SPEC),)))
    assert again.outcome is Outcome.PULLED


def test_a_silent_registry_is_a_warning_and_denied_credentials_an_error(ws):
    engine = FakeEngine(registry_answer=RegistryStatus.UNREACHABLE)
    events: list = []
    (result,) = cache_runner(engine, events).run(Plan(ws, (EnsureImage(SPEC),)))
    assert result.outcome is Outcome.BUILT and "did not answer" in notes(events)
    engine = FakeEngine(registry_answer=RegistryStatus.DENIED)
    with pytest.raises(RegistryError, match="refused the engine's credentials") as caught:
        cache_runner(engine, []).run(Plan(ws, (EnsureImage(SPEC),)))
    assert caught.value.exit_code == 2 and "docker login registry.example.com" in caught.value.hint
    assert engine.builds == []


def test_a_registry_that_did_not_answer_is_not_asked_again_in_the_same_run(ws):
    """A registry that takes connections and never answers was asked for each keyed image of the
    run (build, runtime, test, each chip's micro-ROS): its timeout, 25 s, of silence for each."""
    engine = FakeEngine(registry_answer=RegistryStatus.UNREACHABLE)
    asked: list[str] = []
    ask = engine.pull_cached
    engine.pull_cached = lambda ref: asked.append(ref) or ask(ref)  # type: ignore[method-assign]
    other = ros_build_image(Config(ros_distro="humble"), DOCKERFILE, {})
    events: list = []
    results = cache_runner(engine, events).run(Plan(ws, (EnsureImage(SPEC), EnsureImage(other))))
    assert [r.outcome for r in results] == [Outcome.BUILT, Outcome.BUILT] and asked == [REMOTE]
    assert f"cache registry {REGISTRY} did not answer earlier in this run; building locally" in notes(events)


def test_push_cache_pushes_what_the_registry_lacks_and_only_that(ws):
    engine = FakeEngine()
    cache_runner(engine, [], push=True).run(Plan(ws, (EnsureImage(SPEC),)))
    assert engine.pushed == [REMOTE] and REMOTE not in engine.images_by_tag, "pushed, and the push name removed"
    events: list = []
    cache_runner(engine, events, push=True).run(Plan(ws, (EnsureImage(SPEC),)))  # a cache hit, already there
    assert engine.pushed == [REMOTE] and "already in the cache registry" in notes(events)
    cache_runner(engine, []).run(Plan(ws, (EnsureImage(SPEC),)))
    assert engine.pushed == [REMOTE], "no --push-cache, no push"


@pytest.mark.parametrize(
    ("said", "status"),
    [  # what the Docker engine said to a distribution registry, seen on this machine
        ("manifest for 127.0.0.1:5055/espdock/x:1 not found: manifest unknown: manifest unknown", "missing"),
        ('Head "http://127.0.0.1:5055/v2/espdock/x/manifests/1": no basic auth credentials', "denied"),
        ("unauthorized: authentication required", "denied"),
        ('Get "http://127.0.0.1:5999/v2/": dial tcp 127.0.0.1:5999: connect: connection refused', "unreachable"),
    ],
)
def test_registry_answers_are_told_apart(said, status):
    assert registry_answer(said).status == status


def test_a_workspace_without_git_history_builds_with_a_fixed_source_date(ws):
    """A tree from `git archive` or a downloaded zip: no SOURCE_DATE_EPOCH reached the containers,
    and Python wrote .pyc files holding the sources' modification times, which differ with every
    unpacking (the install of one commit differed from a clone's)."""
    engine = FakeEngine(run_script=colcon_installs(ws))
    (ws.ws_dir / "build/espdock-ros").mkdir(parents=True)
    assert not (ws.root / ".git").exists()
    runner(engine, []).run(Plan(ws, (COLCON,)))
    (colcon,) = [run for run in engine.runs if "colcon" in run.argv[-1] or "colcon" in run.argv]
    assert ("SOURCE_DATE_EPOCH", "315532800") in colcon.env


def test_image_builds_get_the_source_date_but_it_is_not_part_of_the_key(ws):
    engine = FakeEngine()
    Runner(engine, Config(), {"SOURCE_DATE_EPOCH": "1767323045"}, [].append, (os.getuid(), os.getgid())).run(
        Plan(ws, (EnsureImage(SPEC),))
    )
    (build,) = engine.builds
    assert build["build_args"]["SOURCE_DATE_EPOCH"] == "1767323045"
    assert build["tag"] == SPEC.tag == ros_build_image(Config(), DOCKERFILE, {}).tag


def test_without_a_terminal_every_line_is_printed_and_timestamps_are_optional():
    import io
    import re

    from rich.console import Console

    from espdock.cli.ui import Reporter
    from espdock.events import StepOutput, StepStarted

    out = io.StringIO()
    reporter = Reporter(Console(file=out, force_terminal=False, width=200), timestamps=True)
    for event in (
        StepStarted("image x"),
        StepOutput("image x", "#5 [build 2/3] RUN pip install", progress=True),
        StepFinished("image x", Outcome.BUILT, 1.0, "x:1"),
    ):
        reporter(event)
    reporter.summary()  # the table that ends the build: its lines were the only ones left untimed
    lines = out.getvalue().splitlines()
    assert any("RUN pip install" in line for line in lines), "image build progress reaches a CI log"
    assert any("espdock build" in line for line in lines) and any("x:1" in line for line in lines), lines
    assert lines and all(re.match(r"\d\d:\d\d:\d\d ", line) for line in lines), lines


def test_a_step_silent_in_a_log_is_said_to_be_still_running_until_it_finishes(monkeypatch):
    """A CI log: a cache push of 40 s, a CMake configure of 75 s printed nothing between the step's
    name and its end, where a terminal's status line shows it alive."""
    import io
    import re

    from rich.console import Console

    from espdock.cli.ui import Reporter
    from espdock.events import StepStarted

    monkeypatch.setattr(Reporter, "SILENT", 0.3)
    monkeypatch.setattr(Reporter, "_LOOK_EVERY", 0.02)
    out = io.StringIO()
    reporter = Reporter(Console(file=out, force_terminal=False, width=200))
    try:
        reporter(StepStarted("image espdock/ros-jazzy-build"))
        deadline = time.monotonic() + 10
        while "still running" not in out.getvalue() and time.monotonic() < deadline:
            time.sleep(0.02)
        assert re.search(r"^  image espdock/ros-jazzy-build: still running, \d+ s in, \d+ s without output$",
                         out.getvalue(), re.M), out.getvalue()  # fmt: skip
        reporter(StepFinished("image espdock/ros-jazzy-build", Outcome.PULLED, 1.0, ""))
        said = out.getvalue()
        time.sleep(0.6)  # twice the silence: a finished step is no longer said
        assert out.getvalue() == said
    finally:
        reporter.close()


def test_a_tool_s_output_reaches_a_log_exactly_as_rich_prints_it():
    import io

    from rich.console import Console
    from rich.text import Text

    from espdock.cli.ui import Reporter

    lines = ["plain", "a\rcarriage return", "x" * 300, "[bold]not markup[/bold]", "tab\there", "bell\x07", "ünï ✓"]
    fast, ref = io.StringIO(), io.StringIO()
    reporter, console = Reporter(Console(file=fast, width=80)), Console(file=ref, width=80)
    for line in lines:
        reporter.line(line)
        console.print(Text(line), soft_wrap=True)
    assert fast.getvalue() == ref.getvalue()


STATUS = """Package: libc6
Status: install ok installed
Version: 2.36-9
Description: GNU C Library
 multi-line description: Version: 0

Package: gone
Status: deinstall ok not-installed
Version: 1.0

Package: python3
Status: install ok installed
Multi-Arch: allowed
Version: 3.11.2-1+b1
"""


def test_a_built_image_records_its_debian_packages_in_labels_without_running_it(ws):
    engine = FakeEngine(files={DPKG_STATUS: STATUS.encode()})
    events: list = []
    runner(engine, events).run(Plan(ws, (EnsureImage(SPEC),)))
    labels = engine.images_by_tag[SPEC.tag].labels
    assert labels["io.espdock.debian-packages"] == "libc6=2.36-9 python3=3.11.2-1+b1"
    assert labels["io.espdock.key"] == SPEC.key, "the key label stays"
    assert "2 Debian packages recorded" in notes(events)
    assert engine.reads == [(SPEC.tag, DPKG_STATUS)] and engine.runs == [], "read from the image, no container run"


def test_an_image_build_interrupted_before_its_packages_were_recorded_has_them_recorded_on_the_next_hit(
    ws, monkeypatch
):
    """Ctrl-C just after BuildKit tagged the image, before its package set was added to its labels:
    the tag kept its base image's package set, and every later build took it for a hit as it was."""
    engine = FakeEngine(files={DPKG_STATUS: STATUS.encode()})
    labelled = engine.add_labels

    def interrupted(ref, labels):
        raise KeyboardInterrupt

    monkeypatch.setattr(engine, "add_labels", interrupted)
    with pytest.raises(KeyboardInterrupt):
        runner(engine, []).run(Plan(ws, (EnsureImage(SPEC),)))
    monkeypatch.setattr(engine, "add_labels", labelled)
    events: list = []
    runner(engine, events).run(Plan(ws, (EnsureImage(SPEC),)))
    assert len(engine.builds) == 1, "the image is not built again: only its labels were missing"
    assert engine.images_by_tag[SPEC.tag].labels["io.espdock.debian-packages"] == "libc6=2.36-9 python3=3.11.2-1+b1"
    assert "its build was interrupted before its packages were recorded" in notes(events)
    events.clear()
    reads = len(engine.reads)
    runner(engine, events).run(Plan(ws, (EnsureImage(SPEC),)))
    assert "interrupted" not in notes(events) and len(engine.reads) == reads, "recorded once"


def test_an_image_without_dpkg_is_built_with_a_warning_and_no_package_labels(ws):
    engine = FakeEngine(files={DPKG_STATUS: None})
    events: list = []
    runner(engine, events).run(Plan(ws, (EnsureImage(SPEC),)))
    assert "io.espdock.debian-packages" not in engine.images_by_tag[SPEC.tag].labels
    assert "warning: no dpkg in the image: its package set is not recorded" in notes(events)


def test_after_an_edit_colcon_gets_the_changed_package_and_its_dependents_only(ws):
    engine = FakeEngine(run_script=colcon_installs(ws))
    runner(engine, []).run(Plan(ws, (COLCON,)))
    assert "--packages-select" not in engine.runs[-1].argv
    (ws.root / "ws/src/app/node.py").write_text("print(1)\n")
    events: list = []
    runner(engine, events).run(Plan(ws, (COLCON,)))
    argv = engine.runs[-1].argv
    assert argv[argv.index("--packages-select") : argv.index("--cmake-args")] == ("--packages-select", "app")
    assert events[-1].detail == "1 package(s) built, 1 up to date"
    (ws.root / "ws/src/msgs/msg.txt").write_text("x")
    runner(engine, []).run(Plan(ws, (COLCON,)))
    assert "--packages-select" not in engine.runs[-1].argv, "msgs changed: app depends on it, both rebuild"


def test_stale_interfaces_and_a_native_symlink_install_are_both_cleared_before_colcon(ws):
    """Two reasons to clear trees in one build: app's interfaces use msgs's, which changed, and a
    native `colcon build --symlink-install` linked both install prefixes to this machine's paths."""
    from dataclasses import replace

    step = replace(COLCON, interfaces=("msgs", "app"))
    engine = FakeEngine(run_script=colcon_installs(ws))
    first: list = []
    runner(engine, first).run(Plan(ws, (step,)))
    # A first build has nothing to build afresh (it said it built app afresh, its deps "changed").
    assert "afresh" not in notes(first)
    for name in ("msgs", "app"):
        share = ws.ws_dir / "install" / name / "share" / name
        share.mkdir(parents=True)
        (share / "package.xml").symlink_to(ws.root / "ws/src" / name / "package.xml")
    (ws.ws_dir / "build/espdock-ros/app/rosidl_generator_type_description").mkdir(parents=True)
    (ws.root / "ws/src/msgs/msg.txt").write_text("x")
    seen: list[bool] = []
    play = colcon_installs(ws)

    def checked(spec, on_line):
        seen.append(
            any((ws.ws_dir / "install" / n / "share" / n / "package.xml").is_symlink() for n in ("msgs", "app"))
        )
        seen.append((ws.ws_dir / "build/espdock-ros/app").exists())
        return play(spec, on_line)

    engine.run_script = checked
    events: list = []
    runner(engine, events).run(Plan(ws, (step,)))
    assert seen == [False, False], "colcon ran on a native link or on app's old type descriptions"
    assert "building app afresh" in notes(events)
    assert "removed the install prefixes of msgs, app" in notes(events)


@pytest.mark.parametrize("option", ["--packages-skip", "--packages-ignore"])
def test_what_built_on_a_changed_package_left_out_is_built_again_once_that_is_built(ws, option):
    """`-- --packages-skip msgs` after an edit of msgs: app built on msgs's old install. The next
    plain build built msgs alone and called app up to date, on msgs's old headers for good."""
    engine = FakeEngine(run_script=colcon_installs(ws))
    runner(engine, []).run(Plan(ws, (COLCON,)))
    (ws.root / "ws/src/msgs/msg.txt").write_text("x")
    events: list = []
    runner(engine, events).run(Plan(ws, (replace(COLCON, colcon_args=(option, "msgs")),)))
    assert events[-1].detail == "1 package(s) built, 0 up to date, 1 not built (msgs)"
    assert "app built on the old install of msgs, which this build did not build" in notes(events)
    check_built_by_espdock(ws, "app")  # built, by espdock: `espdock run` takes it meanwhile
    runner(engine, []).run(Plan(ws, (COLCON,)))
    assert "--packages-select" not in engine.runs[-1].argv, "msgs is built now: app must be built again on it"
    runner(engine, events := []).run(Plan(ws, (COLCON,)))
    assert events[-1].detail == "up to date (2 package(s))"


def test_a_package_that_moved_is_built_afresh_in_a_new_build_dir(ws):
    """An upstream restructure moved app's directory with its contents unchanged: the build said
    up to date, and a symlink install's links and the CMake cache named the old directory."""
    engine = FakeEngine(run_script=colcon_installs(ws))
    runner(engine, []).run(Plan(ws, (COLCON,)))
    (ws.ws_dir / "build/espdock-ros/app").mkdir(parents=True)
    (ws.ws_dir / "build/espdock-ros/app/CMakeCache.txt").write_text(
        "CMAKE_HOME_DIRECTORY:INTERNAL=/workspace/ws/src/app\n"
    )
    (ws.ws_dir / "src/apps").mkdir()
    (ws.ws_dir / "src/app").rename(ws.ws_dir / "src/apps/app")
    moved = replace(COLCON, sources=(("msgs", "src/msgs"), ("app", "src/apps/app")))
    play = colcon_installs(ws)
    cached: list[bool] = []

    def checked(spec, on_line):
        cached.append((ws.ws_dir / "build/espdock-ros/app/CMakeCache.txt").exists())
        return play(spec, on_line)

    engine.run_script = checked
    events: list = []
    runner(engine, events).run(Plan(ws, (moved,)))
    argv = engine.runs[-1].argv
    assert argv[argv.index("--packages-select") : argv.index("--cmake-args")] == ("--packages-select", "app")
    assert cached == [False], "colcon ran on the build dir configured from src/app"
    assert "building afresh what moved since the last build: app (from src/app)" in notes(events)
    runner(engine, events := []).run(Plan(ws, (moved,)))
    assert events[-1].detail == "up to date (2 package(s))"


def test_what_an_older_espdock_recorded_is_built_again_afresh(ws):
    """An upgrade, or a colleague's older espdock rebuilding in the same checkout: its records
    say neither where a package was built from nor whether it was built on a dependency's old
    install, and were trusted as they were: a package moved under it was "up to date", then failed
    at the next edit in the CMake cache of its old directory, and --force failed the same way."""
    import json

    engine = FakeEngine(run_script=colcon_installs(ws))
    runner(engine, []).run(Plan(ws, (COLCON,)))
    stamps = ws.ws_dir / "build/.espdock-colcon-stamps.json"
    older = {
        name: {"stamp": e["stamp"], "installed": e["installed"]} for name, e in json.loads(stamps.read_text()).items()
    }
    stamps.write_text(json.dumps(older))
    (ws.ws_dir / "build/espdock-ros/app").mkdir(parents=True)
    (ws.ws_dir / "build/espdock-ros/app/CMakeCache.txt").write_text("CMAKE_HOME_DIRECTORY:INTERNAL=/elsewhere\n")
    events: list = []
    runner(engine, events).run(Plan(ws, (COLCON,)))
    assert "building afresh what an older espdock built: msgs, app" in notes(events)
    assert not (ws.ws_dir / "build/espdock-ros/app/CMakeCache.txt").exists()
    runner(engine, events := []).run(Plan(ws, (COLCON,)))
    assert events[-1].detail == "up to date (2 package(s))"


def check_raises_did_not_finish(ws, package: str) -> bool:
    from espdock.errors import WorkspaceError

    (ws.ws_dir / "build/espdock-ros" / package).mkdir(parents=True, exist_ok=True)
    with pytest.raises(WorkspaceError, match="did not finish"):
        check_built_by_espdock(ws, package)
    return True


def test_a_package_whose_build_failed_and_that_then_moved_is_built_afresh(ws):
    """The first build of app fails; app is moved and fixed: its build dir was configured from the
    old directory, and CMake failed on "The source directory ... does not exist", --force too."""
    engine = FakeEngine(run_script=colcon_installs(ws, code=1, rcs={"msgs": 0, "app": 1}))
    with pytest.raises(BuildFailed):
        runner(engine, []).run(Plan(ws, (COLCON,)))
    assert check_raises_did_not_finish(ws, "app")
    (ws.ws_dir / "build/espdock-ros/app").mkdir(parents=True, exist_ok=True)
    (ws.ws_dir / "build/espdock-ros/app/CMakeCache.txt").write_text(
        "CMAKE_HOME_DIRECTORY:INTERNAL=/workspace/ws/src/app\n"
    )
    (ws.ws_dir / "src/apps").mkdir()
    (ws.ws_dir / "src/app").rename(ws.ws_dir / "src/apps/app")
    moved = replace(COLCON, sources=(("msgs", "src/msgs"), ("app", "src/apps/app")))
    engine.run_script = colcon_installs(ws)
    events: list = []
    runner(engine, events).run(Plan(ws, (moved,)))
    assert "building afresh what moved since the last build: app (from src/app)" in notes(events)
    assert not (ws.ws_dir / "build/espdock-ros/app/CMakeCache.txt").exists()


def test_sources_put_back_with_an_older_time_and_force_build_afresh_and_an_edit_does_not(ws):
    """A source put back from a backup (`cp -p`, `git archive | tar -x`): espdock saw the change
    and ran colcon, and make, deciding by time, kept the old binary; `--force` did the same."""
    from dataclasses import replace

    engine = FakeEngine(run_script=colcon_installs(ws))
    source = ws.ws_dir / "src/app/main.c"
    source.write_text("int main(void) { return 42; }\n")
    runner(engine, []).run(Plan(ws, (COLCON,)))
    cache = ws.ws_dir / "build/espdock-ros/app/CMakeCache.txt"

    def configured() -> None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        cache.write_text("CMAKE_HOME_DIRECTORY:INTERNAL=/workspace/ws/src/app\n")

    configured()
    before = source.stat().st_mtime_ns
    source.write_text("int main(void) { return 7; }\n")  # an edit: newer, as make sees it
    os.utime(source, ns=(before + 10**9, before + 10**9))
    runner(engine, events := []).run(Plan(ws, (COLCON,)))
    assert "afresh" not in notes(events) and cache.exists()
    source.write_text("int main(void) { return 42; }\n")  # the backup put back, with its time
    os.utime(source, ns=(before, before))
    runner(engine, events := []).run(Plan(ws, (COLCON,)))
    assert "building afresh what changed with no newer file: app" in notes(events)
    assert not cache.exists()
    configured()
    runner(engine, events := []).run(Plan(ws, (replace(COLCON, force=True),)))
    assert "--force: building 2 package(s) afresh" in notes(events) and not cache.exists()


def test_a_node_script_made_executable_after_its_build_is_built_afresh(ws):
    """`ros2 run` says "No executable found" of a node script committed without its x bit; the
    user runs `chmod +x` and builds again. The build said its packages were up to date, and the
    install (which copies the source's mode) kept the script not executable."""
    engine = FakeEngine(run_script=colcon_installs(ws))
    script = ws.ws_dir / "src/app/scripts/teleop.py"
    script.parent.mkdir()
    script.write_text("#!/usr/bin/env python3\n")
    script.chmod(0o644)
    runner(engine, []).run(Plan(ws, (COLCON,)))
    runs = len(engine.runs)
    script.chmod(0o755)
    runner(engine, events := []).run(Plan(ws, (COLCON,)))
    assert len(engine.runs) == runs + 1, "chmod +x built nothing"
    assert "building afresh what changed with no newer file: app" in notes(events)
    assert "x bit changed" in notes(events)


def test_a_source_removed_beside_an_edit_builds_afresh_and_an_editor_leftover_does_not(ws):
    """A branch switch removes one file and edits another: the edit is newer than the last build,
    so nothing was built afresh, and what the removed file installed stayed in install/."""
    engine = FakeEngine(run_script=colcon_installs(ws))
    app = ws.ws_dir / "src/app"
    (app / "extra.c").write_text("int extra(void) { return 1; }\n")
    (app / "main.c").write_text("int main(void) { return 7; }\n")
    (app / "main.c~").write_text("int main(void) { return 0; }\n")
    runner(engine, []).run(Plan(ws, (COLCON,)))
    cache = ws.ws_dir / "build/espdock-ros/app/CMakeCache.txt"
    cache.parent.mkdir(parents=True, exist_ok=True)
    cache.write_text("CMAKE_HOME_DIRECTORY:INTERNAL=/workspace/ws/src/app\n")
    (app / "main.c~").unlink()
    (app / "main.c").write_text("int main(void) { return 8; }\n")
    runner(engine, events := []).run(Plan(ws, (COLCON,)))
    assert "afresh" not in notes(events) and cache.exists(), notes(events)
    (app / "extra.c").unlink()
    (app / "main.c").write_text("int main(void) { return 9; }\n")
    later = time.time_ns() + 10**9
    os.utime(app / "main.c", ns=(later, later))  # newer than anything the last build saw
    engine.run_script = colcon_installs(ws, code=1, rcs={"msgs": 0, "app": 1})
    with pytest.raises(BuildFailed):  # a failed build between: the next still knows what went
        runner(engine, []).run(Plan(ws, (COLCON,)))
    cache.parent.mkdir(parents=True, exist_ok=True)
    cache.write_text("CMAKE_HOME_DIRECTORY:INTERNAL=/workspace/ws/src/app\n")
    engine.run_script = colcon_installs(ws)
    stale = ws.ws_dir / "install/app/lib/libextra.so"  # what extra.c built and installed
    stale.parent.mkdir(parents=True, exist_ok=True)
    stale.write_text("old")
    runner(engine, events := []).run(Plan(ws, (COLCON,)))
    said = notes(events)
    assert "installing afresh what lost source files since its last build: app (extra.c)" in said
    assert "building app afresh" not in said, "CMake installs every file again; its build stays incremental"
    assert not stale.exists() and cache.parent.is_dir()
    # It configures again (a file(GLOB) of its sources kept the lost one), its compile incremental.
    assert "configuring app again" in said and not cache.exists()
    cache.write_text("CMAKE_HOME_DIRECTORY:INTERNAL=/workspace/ws/src/app\n")
    # A lost interface: rosidl's generated code of it in the build dir failed the next build.
    (ws.ws_dir / "src/msgs/Old.msg").write_text("int32 x\n")
    runner(engine, []).run(Plan(ws, (COLCON,)))
    (ws.ws_dir / "src/msgs/Old.msg").unlink()
    (ws.ws_dir / "src/msgs/New.msg").write_text("int32 y\n")
    generated = ws.ws_dir / "build/espdock-ros/msgs/rosidl_generator_c/old.h"
    generated.parent.mkdir(parents=True)
    generated.write_text("/* generated */\n")
    runner(engine, events := []).run(Plan(ws, (COLCON,)))
    assert "msgs (Old.msg)" in notes(events) and "building msgs afresh as well" in notes(events)
    assert not generated.exists()
    # A branch's new file in a build that failed, then back: what that build installed of it goes.
    # (Newer than the last build: one built afresh that fails gets its old install back, whole.)
    (app / "branch.c").write_text("int branch(void) { return 1; }\n")
    later = time.time_ns() + 3 * 10**9
    os.utime(app / "branch.c", ns=(later, later))
    failing = colcon_installs(ws, code=1, rcs={"msgs": 0, "app": 1})

    def installs_some_then_fails(spec, on_line):  # CMake's install step cut off midway
        (ws.ws_dir / "install/app/lib").mkdir(parents=True, exist_ok=True)
        (ws.ws_dir / "install/app/lib/libbranch.so").write_text("branch")
        return failing(spec, on_line)

    engine.run_script = installs_some_then_fails
    with pytest.raises(BuildFailed):
        runner(engine, []).run(Plan(ws, (COLCON,)))
    (app / "branch.c").unlink()
    engine.run_script = colcon_installs(ws)
    runner(engine, events := []).run(Plan(ws, (COLCON,)))
    assert "app (branch.c" in notes(events), notes(events)
    # A launch file of a CMake package is no module of its build dir: the compile stays incremental.
    (app / "launch").mkdir()
    (app / "launch/robot.launch.py").write_text("def generate_launch_description(): ...\n")
    runner(engine, []).run(Plan(ws, (COLCON,)))
    (app / "launch/robot.launch.py").rename(app / "launch/bringup.launch.py")
    later = time.time_ns() + 2 * 10**9
    os.utime(app / "launch/bringup.launch.py", ns=(later, later))  # as git's checkout writes it
    runner(engine, events := []).run(Plan(ws, (COLCON,)))
    assert "app (launch/robot.launch.py)" in notes(events) and "building app afresh" not in notes(events)


def test_a_symlink_switch_says_which_removed_install_the_options_leave_out(ws):
    """`-- --symlink-install --packages-skip app` after a plain build: app's install went with
    the others' and nothing said it was not built again. colcon does not touch it: it stays."""
    engine = FakeEngine(run_script=colcon_installs(ws))
    (ws.ws_dir / "build/espdock-ros").mkdir(parents=True)  # colcon's build base, where the options are kept
    runner(engine, []).run(Plan(ws, (COLCON,)))
    events: list = []
    # The planner's settings digest: another kind of install changes every package's stamp.
    linked = replace(COLCON, colcon_args=("--symlink-install", "--packages-skip", "app"),
                     settings=(("msgs", "symlink"), ("app", "symlink")))  # fmt: skip
    runner(engine, events).run(Plan(ws, (linked,)))
    assert "app, which the options after `--` leave out, keep theirs until built" in notes(events)
    assert (ws.ws_dir / "install/app").is_dir()


def test_with_continue_on_error_what_built_is_kept_and_what_failed_is_not(ws):
    from dataclasses import replace

    step = replace(COLCON, depends=(("msgs", ()), ("app", ())), colcon_args=("--continue-on-error",))
    engine = FakeEngine(run_script=colcon_installs(ws, code=1, rcs={"msgs": 0, "app": 1}))
    with pytest.raises(BuildFailed) as err:
        runner(engine, []).run(Plan(ws, (step,)))
    assert "failed (exit code 1) in app" in err.value.message
    assert "that built are kept" in (err.value.hint or "")
    engine.run_script = colcon_installs(ws)
    runner(engine, []).run(Plan(ws, (step,)))
    argv = engine.runs[-1].argv
    assert argv[argv.index("--packages-select") : argv.index("--cmake-args")] == (
        "--packages-select",
        "app",
        "--continue-on-error",
    )


def test_a_failure_after_an_earlier_colcon_build_of_the_run_says_what_that_one_built(ws):
    """`espdock test` builds the dependencies first, then the packages tested: a failure of the second
    said "No package was built by this run" after the first had built one, which it keeps."""
    depends = (("msgs", ()), ("app", ("msgs",)))
    first = replace(COLCON, depends=depends, selected=("msgs",), name="colcon build: dependencies")
    second = replace(COLCON, depends=depends, selected=("app",), name="colcon build: with tests")
    fine, failing = colcon_installs(ws), colcon_installs(ws, code=1, rcs={"app": 1})

    engine = FakeEngine(run_script=lambda spec, on_line: (failing if "app" in _selected(spec) else fine)(spec, on_line))
    with pytest.raises(BuildFailed) as err:
        runner(engine, []).run(Plan(ws, (first, second)))
    assert "The 1 package(s) that built are kept" in (err.value.hint or ""), err.value.hint


def _selected(spec) -> tuple[str, ...]:
    argv = list(spec.argv)
    if "--packages-select" not in argv:
        return ()
    rest = argv[argv.index("--packages-select") + 1 :]
    return tuple(rest[: next((i for i, a in enumerate(rest) if a.startswith("-")), len(rest))])


def test_colcon_stopping_before_any_package_is_a_user_error_and_stamps_nothing(ws):
    from espdock.errors import ConfigError

    def refuses(spec, on_line):
        on_line("colcon build: error: unrecognized arguments: --no-such-option")
        return 2

    engine = FakeEngine(run_script=refuses)
    with pytest.raises(ConfigError, match="unrecognized arguments: --no-such-option") as err:
        runner(engine, []).run(Plan(ws, (COLCON,)))
    assert err.value.exit_code == 2
    assert not (ws.ws_dir / "build/.espdock-colcon-stamps.json").exists()


def test_the_users_colcon_defaults_file_is_mounted_where_colcon_reads_it(ws, tmp_path):
    from dataclasses import replace

    defaults = tmp_path / "defaults.yaml"
    defaults.write_text("build: {symlink-install: true}\n")
    engine = FakeEngine(run_script=colcon_installs(ws))
    runner(engine, []).run(Plan(ws, (replace(COLCON, defaults_file=str(defaults)),)))
    spec = engine.runs[-1]
    assert ("COLCON_DEFAULTS_FILE", "/run/espdock/colcon-defaults.yaml") in spec.env
    assert any(m.source == defaults and m.read_only for m in spec.mounts)


def test_a_second_build_in_the_same_workspace_is_told_who_holds_it(ws):
    """A build waiting on another one's lock names that build's pid and command."""
    from espdock.errors import WorkspaceError
    from espdock.workspace import workspace_lock

    with build_holding(ws.root, "build", "talker_py") as process:
        with pytest.raises(WorkspaceError) as error, workspace_lock(ws):
            pass
        assert f"(pid {process.pid}: espdock build talker_py)" in error.value.message
    with workspace_lock(ws):  # the holder's end frees it
        pass


class SlowBuilds(FakeEngine):
    """FakeEngine whose image builds take a while and count how many run at once."""

    def __init__(self) -> None:
        super().__init__()
        self.active = 0
        self.most_at_once = 0
        self.counting = threading.Lock()
        self.started = 0
        self.second_started = threading.Event()

    def build_image(self, **kwargs) -> None:
        with self.counting:
            self.active += 1
            self.most_at_once = max(self.most_at_once, self.active)
            self.started += 1
            if self.started == 2:
                self.second_started.set()
        time.sleep(0.4)
        with self.counting:
            self.active -= 1
        super().build_image(**kwargs)


def lock_files(tmp: Path) -> list[str]:
    return sorted(p.name for p in tmp.glob("espdock-image-*.lock"))


def test_an_image_build_leaves_no_lock_file_in_the_temp_dir(ws, tmp_path, monkeypatch):
    monkeypatch.setattr(machine_lock, "LOCK_DIR", tmp_path)
    engine = FakeEngine()
    runner(engine, []).run(Plan(ws, (EnsureImage(SPEC),)))
    assert [b["tag"] for b in engine.builds] == [SPEC.tag]
    assert lock_files(tmp_path) == []


def test_builds_of_one_tag_wait_for_each_other_even_as_lock_files_go(tmp_path, monkeypatch):
    """Three builds of one tag from three workspaces, the third starting once the second builds,
    the first having removed the lock file the second waited on: still one build at a time."""
    monkeypatch.setattr(bootstrap, "ensure_compose", lambda env, notify: None)
    temp = tmp_path / "tmp"
    temp.mkdir()
    monkeypatch.setattr(machine_lock, "LOCK_DIR", temp)

    # Each build with a temp dir of its own (a CI runner's per-job TMPDIR): the lock is not in it.
    def job_temp() -> str:
        own = tmp_path / f"job-{threading.get_ident()}"
        own.mkdir(exist_ok=True)
        return str(own)

    monkeypatch.setattr(tempfile, "gettempdir", job_temp)
    engine = SlowBuilds()
    events: list = []
    failures: list[BaseException] = []

    def build(name: str) -> None:
        root = tmp_path / name
        (root / "ws/src").mkdir(parents=True)
        try:
            runner(engine, events).run(Plan(Workspace(root), (EnsureImage(SPEC, force=True),)))
        except BaseException as exc:  # reported by the assertion below
            failures.append(exc)

    threads = [threading.Thread(target=build, args=(f"w{i}",)) for i in range(3)]
    threads[0].start()
    time.sleep(0.1)
    threads[1].start()
    assert engine.second_started.wait(10)
    threads[2].start()
    for thread in threads:
        thread.join(10)
    assert failures == []
    assert len(engine.builds) == 3
    assert engine.most_at_once == 1, "two builds of one tag ran at once"
    # Naming the holder, as a second build in one workspace is told: a wait on a stopped one was silent.
    waiting = f"another espdock (pid {os.getpid()}: "
    assert any(isinstance(e, StepNote) and waiting in e.text and "is making it; waiting" in e.text for e in events)
    assert lock_files(temp) == []


def test_the_summary_in_an_80_column_log_cuts_no_step_name_short():
    """Without a terminal (a CI log) the table is 80 columns wide: a micro-ROS image step came out
    as `espdock/idf-micro-ros-jazz…`, its chip and key lost."""
    import io

    from rich.console import Console

    from espdock.cli.ui import Reporter
    from espdock.events import Outcome, StepFinished

    out = io.StringIO()
    reporter = Reporter(Console(file=out, width=80, soft_wrap=True))
    tag = "espdock/idf-micro-ros-jazzy-esp32c3:0123456789abcdef"
    reporter.finished.append(StepFinished(f"image {tag}", Outcome.BUILT, 12.3, tag))
    reporter.summary()
    cells = "".join(line.split("│")[1].strip() for line in out.getvalue().splitlines() if line.startswith("│"))
    assert f"image{tag}" in cells.replace(" ", ""), out.getvalue()
    assert "…" not in out.getvalue()
    # Each on one line, whole: folded at 80 columns, `grep` found neither the tag nor the path.
    installed = "install/led_strip_node/share/led_strip_node/firmware"
    reporter.finished[:] = [StepFinished(f"image {tag}", Outcome.BUILT, 12.3, tag)]
    reporter.finished.append(StepFinished("install led_strip_node", Outcome.BUILT, 0.1, installed))
    out.seek(0), out.truncate()
    reporter.summary()
    assert (
        len([line for line in out.getvalue().splitlines() if f"image {tag}" in line and tag in line.split("│")[-2]])
        == 1
    )
    assert len([line for line in out.getvalue().splitlines() if installed in line]) == 1, out.getvalue()


def test_symlink_install_turned_on_in_the_colcon_defaults_file_is_a_switch_and_on_in_both_is_none(ws):
    """A switch made in ~/.colcon/defaults.yaml failed an interface package, one per run ("its build
    dir is from a build without --symlink-install"); `-- --symlink-install` with it already on
    there said "on since the last build" and rebuilt everything from scratch."""
    from dataclasses import replace

    engine = FakeEngine(run_script=colcon_installs(ws))
    (ws.ws_dir / "build/espdock-ros").mkdir(parents=True)
    runner(engine, []).run(Plan(ws, (COLCON,)))
    events: list = []
    on_in_defaults = replace(COLCON, defaults_symlink_install=True, force=True)
    runner(engine, events).run(Plan(ws, (on_in_defaults,)))
    assert "--symlink-install on since their last build" in notes(events)
    events.clear()
    runner(engine, events).run(Plan(ws, (replace(on_in_defaults, colcon_args=("--symlink-install",)),)))
    assert "since their last build" not in notes(events)


def test_a_selection_s_switch_of_the_install_kind_is_its_own_and_the_rest_switch_when_built(ws):
    """`espdock build msgs -- --symlink-install`, then `espdock build -- --symlink-install`: the
    switch, kept for the workspace, seemed done, and app's copying build dir was built in place
    (colcon failed on an interface package's; the other way round, its install links stayed)."""
    from dataclasses import replace

    engine = FakeEngine(run_script=colcon_installs(ws))
    (ws.ws_dir / "build/espdock-ros").mkdir(parents=True)
    runner(engine, []).run(Plan(ws, (COLCON,)))
    events: list = []
    # The options decide the stamps (through each package's colcon settings digest).
    linked = {"colcon_args": ("--symlink-install",), "settings": (("msgs", "linked"), ("app", "linked"))}
    msgs_only = replace(COLCON, packages=("msgs",), sources=COLCON.sources[:1], depends=COLCON.depends[:1])
    runner(engine, events).run(Plan(ws, (replace(msgs_only, whole=False, **linked),)))
    assert "removed the build dirs and install prefixes of 1 package(s)" in notes(events)
    # A selection's options are not the workspace's: `espdock test` and `run` judge by the whole build's.
    from espdock.ros.trees import last_build_args

    assert last_build_args(ws.ws_dir / "build/espdock-ros") == ()
    events.clear()
    (ws.ws_dir / "build/espdock-ros/app/CMakeCache.txt").parent.mkdir(parents=True, exist_ok=True)
    (ws.ws_dir / "build/espdock-ros/app/CMakeCache.txt").write_text("AMENT_CMAKE_SYMLINK_INSTALL:BOOL=OFF\n")
    runner(engine, events).run(Plan(ws, (replace(COLCON, **linked),)))
    assert "--symlink-install on since their last build: removed the build dirs and install prefixes of 1" in notes(
        events
    )
    assert not (ws.ws_dir / "build/espdock-ros/app/CMakeCache.txt").exists(), "app's copying build dir went first"


def test_what_a_switch_removes_comes_back_when_colcon_refuses_its_options(ws):
    """`espdock build -- --symlink-install --bogus-flag`: espdock removed the packages' build dirs
    and install prefixes for the switch, then colcon refused the options and built nothing: the
    packages stayed uninstalled until the next build."""
    from dataclasses import replace

    (ws.ws_dir / "build/espdock-ros").mkdir(parents=True)
    runner(FakeEngine(run_script=colcon_installs(ws)), []).run(Plan(ws, (COLCON,)))
    install = ws.ws_dir / "install"
    before = {p.relative_to(install).as_posix() for p in install.rglob("*")}
    assert {"msgs", "app"} <= before

    def refuse(spec, on_line):
        on_line("colcon: error: unrecognized arguments: --bogus-flag")
        return 2

    linked = {"colcon_args": ("--symlink-install", "--bogus-flag"), "settings": (("msgs", "l"), ("app", "l"))}
    with pytest.raises(ConfigError, match=r"bogus-flag|stopped before building"):
        runner(FakeEngine(run_script=refuse), []).run(Plan(ws, (replace(COLCON, **linked),)))
    assert {p.relative_to(install).as_posix() for p in install.rglob("*")} == before
    assert not (ws.ws_dir / "build/espdock-ros/.espdock-afresh").exists()


def test_a_menuconfig_change_of_an_option_the_chip_s_defaults_file_sets_names_that_file(ws):
    """The warning said to run save-defconfig, which writes sdkconfig.defaults: the chip's
    sdkconfig.defaults.<chip> setting the option won over it, and the change was lost, unsaid."""
    project = ws.root / "src/led_fw"
    project.mkdir(parents=True)
    (project / "sdkconfig.defaults").write_text("CONFIG_FREERTOS_HZ=100\n")
    (project / "sdkconfig.defaults.esp32c3").write_text("CONFIG_FREERTOS_HZ=100\n")
    sdkconfig = ws.ws_dir / "build/led_fw/sdkconfig"

    def configure(spec, on_line):
        if not sdkconfig.is_file():  # IDF makes it from the defaults files, else keeps it
            sdkconfig.parent.mkdir(parents=True, exist_ok=True)
            sdkconfig.write_text("CONFIG_FREERTOS_HZ=100\n")
        return 0

    step = IdfBuild("led_fw", "src/led_fw", "i", "esp32c3", "k")
    engine = FakeEngine(run_script=configure)
    runner(engine, []).run(Plan(ws, (step,)))
    sdkconfig.write_text("CONFIG_FREERTOS_HZ=1000\n")  # menuconfig
    events: list = []
    runner(engine, events).run(Plan(ws, (step,)))
    said = " ".join(notes(events).split())
    assert "CONFIG_FREERTOS_HZ=1000 (was 100)" in said
    assert "put the line in src/led_fw/sdkconfig.defaults.esp32c3, which sets CONFIG_FREERTOS_HZ" in said, said


def test_a_base_image_two_builds_miss_at_once_is_made_once(tmp_path, monkeypatch):
    """Two CI jobs on a machine without the base image: both pulled (or ran debootstrap, a minute
    each), and the second import took the tag from the image the first one's builds started from."""
    monkeypatch.setattr(machine_lock, "LOCK_DIR", tmp_path)
    made: list[str] = []
    ref = "debian:trixie-slim"

    class SlowPull(FakeEngine):
        def pull(self, wanted: str) -> bool:
            made.append(wanted)
            time.sleep(0.4)
            self.images_by_tag[wanted] = ImageInfo("id", (wanted,), datetime.now(UTC), 1, {})
            return True

    engine = SlowPull()
    hows: list[str] = []
    notes_said: list[str] = []
    threads = [
        threading.Thread(
            target=lambda: hows.append(bootstrap.ensure_base_image(engine, ref, Config(), notes_said.append))
        )
        for _ in range(2)
    ]
    for thread in threads:
        thread.start()
        time.sleep(0.1)
    for thread in threads:
        thread.join(10)
    assert made == [ref] and sorted(hows) == ["present", "pulled"]
    assert any(f"{ref}: another espdock (pid {os.getpid()}: " in note for note in notes_said), notes_said


def test_the_colcon_step_s_status_counts_the_packages_done(ws):
    """At a terminal, a build of 48 packages showed only a spinner beside "colcon build" (colcon's
    own status line says how many are done)."""
    from espdock.events import StepOutput

    lines = (
        "Starting >>> msgs",
        "Finished <<< msgs [0.31s]",
        "Starting >>> app",
        "Failed   <<< app [0.2s, exited with code 1]",
    )
    engine = FakeEngine(run_script=colcon_installs(ws, lines=lines))
    events: list = []
    runner(engine, events).run(Plan(ws, (COLCON,)))
    said = [e.line for e in events if isinstance(e, StepOutput) and e.status]
    assert said == ["1 of 2 package(s) done", "2 of 2 package(s) done"]
    # For a terminal's status line only: a CI log (or --verbose) has colcon's own lines, not these.
    import io

    from rich.console import Console

    from espdock.cli.ui import Reporter

    for verbose in (False, True):
        out = io.StringIO()
        reporter = Reporter(Console(file=out, width=120), verbose=verbose)
        for event in events:
            reporter(event)
        assert "package(s) done" not in out.getvalue() and "Finished <<< msgs" in out.getvalue()


def test_a_build_that_rebuilds_only_python_packages_says_nothing_of_cmake_s_tests(ws):
    """A whole-workspace build on the wheels image that rebuilt only an ament_python package said
    "CMake packages are configured with BUILD_TESTING=OFF" though it configured none."""
    from dataclasses import replace

    step = replace(COLCON, tests_off=True, python=("app",))
    engine = FakeEngine(run_script=colcon_installs(ws))
    first: list = []
    runner(engine, first).run(Plan(ws, (step,)))
    assert "BUILD_TESTING=OFF" in notes(first), "msgs, a CMake package, was configured"
    (ws.root / "ws/src/app/app.txt").write_text("an edit")
    events: list = []
    runner(engine, events).run(Plan(ws, (step,)))
    assert events[-1].detail == "1 package(s) built, 1 up to date"
    assert "BUILD_TESTING" not in notes(events)


def test_a_record_an_espdock_before_file_lists_wrote_builds_its_changed_package_afresh(ws):
    """After an upgrade, the first branch switch left a removed module and script installed for
    good: the older espdock's records, of the same format, kept no list of files to compare."""
    import json

    from espdock.ros.staleness import ROS_STAMPS

    engine = FakeEngine(run_script=colcon_installs(ws))
    app = ws.ws_dir / "src/app"
    (app / "main.c").write_text("int main(void) { return 1; }\n")
    runner(engine, []).run(Plan(ws, (COLCON,)))
    records = ws.ws_dir / "build" / ROS_STAMPS
    older = {name: {k: v for k, v in entry.items() if k not in ("paths", "declares")}
             for name, entry in json.loads(records.read_text()).items()}  # fmt: skip
    records.write_text(json.dumps(older))
    runner(engine, events := []).run(Plan(ws, (COLCON,)))
    assert "afresh" not in notes(events), "nothing changed: up to date"
    (app / "main.c").write_text("int main(void) { return 2; }\n")
    runner(engine, events := []).run(Plan(ws, (COLCON,)))
    assert "building afresh what an older espdock built: app" in notes(events)


def test_the_tests_get_the_caller_s_domain_and_discover_on_their_own_loopback_by_default(ws):
    """Two CI jobs' `espdock test` on one engine: the test containers share its bridge network,
    and each job's DDS tests heard the other's (ROS_DOMAIN_ID did not reach them); the nodes'
    ROS logs went with the container."""
    from espdock.ros.testing import ColconTest

    step = ColconTest(image="i", packages=("app",), sources=(("app", "src/app"),), colcon_args=())

    said: list = []

    def env_of(caller: dict, files: dict | None = None) -> dict:
        engine = FakeEngine(run_script=lambda spec, on_line: 0, files=files or {})
        ran = Runner(engine, Config(), caller, said.append, (os.getuid(), os.getgid()))  # type: ignore[arg-type]
        ran.ros.test_packages(ws, step, lambda line: None)
        return dict(engine.runs[-1].env)

    alone = env_of({"ROS_DOMAIN_ID": "11", "ROS_DISTRO": "humble", "PATH": "/usr/bin"})
    assert alone["ROS_DOMAIN_ID"] == "11" and alone["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert "ROS_DISTRO" not in alone and "PATH" not in alone, "the image's own, not the host's"
    assert alone["ROS_LOG_DIR"] == "/workspace/ws/log/ros" and (ws.ws_dir / "log/ros").is_dir()
    told = env_of({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET", "RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"})
    assert told["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SUBNET" and told["RMW_IMPLEMENTATION"] == "rmw_cyclonedds_cpp"
    assert "ROS_AUTOMATIC_DISCOVERY_RANGE" not in env_of({"ROS_STATIC_PEERS": "10.0.0.2"})
    # An old `export ROS_LOCALHOST_ONLY=0`, which rcl takes as unset, leaves the default as it is.
    assert env_of({"ROS_LOCALHOST_ONLY": "0"})["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    # An RMW the image's index lacks (it has Fast DDS alone): the tests failed to start, their
    # results lost ("fix the tests"). Not passed, and said.
    index = "/opt/espdock/venv/share/ament_index/resource_index/rmw_typesupport/"
    lacking = {index + "rmw_cyclonedds_cpp": None, index + "rmw_fastrtps_cpp": b""}
    assert "RMW_IMPLEMENTATION" not in env_of({"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}, lacking)
    assert "RMW_IMPLEMENTATION=rmw_cyclonedds_cpp (from your environment) is not in i" in notes(said)


def test_the_colcon_build_gets_makeflags_job_limits_and_nothing_else_of_them(ws):
    """`MAKEFLAGS=-j2 espdock build` on a machine of little memory: the container compiled a file
    per core all the same, and the OOM killer ended the build."""
    engine = FakeEngine(run_script=colcon_installs(ws))
    Runner(engine, Config(), {"MAKEFLAGS": "-j2 -k"}, [].append, (os.getuid(), os.getgid())).run(  # type: ignore[arg-type]
        Plan(ws, (COLCON,))
    )
    assert dict(engine.runs[-1].env)["MAKEFLAGS"] == "-j2"
    runs = len(engine.runs)
    Runner(engine, Config(), {}, [].append, (os.getuid(), os.getgid())).run(Plan(ws, (COLCON,)))  # type: ignore[arg-type]
    assert len(engine.runs) == runs, "a job limit changes nothing built: no rebuild"


def test_an_interface_package_whose_cmake_files_changed_is_built_afresh_with_no_build_dir_here(ws):
    """An interface taken out of rosidl_generate_interfaces (its file kept): rosidl's code of it
    stayed in the build dir and was installed again. In volume mode the build dirs are on the
    engine, so what says it generates interfaces is its CMakeLists.txt."""
    engine = FakeEngine(run_script=colcon_installs(ws))
    cmake = ws.ws_dir / "src/msgs/CMakeLists.txt"
    cmake.write_text('project(msgs)\nrosidl_generate_interfaces(${PROJECT_NAME} "msg/Old.msg" "msg/New.msg")\n')
    (ws.ws_dir / "src/app/CMakeLists.txt").write_text("project(app)\nadd_executable(app main.c)\n")
    runner(engine, []).run(Plan(ws, (COLCON,)))
    assert not (ws.ws_dir / "build/espdock-ros/msgs").exists()
    cmake.write_text('project(msgs)\nrosidl_generate_interfaces(${PROJECT_NAME} "msg/New.msg")\n')
    (ws.ws_dir / "src/app/CMakeLists.txt").write_text("project(app)\nadd_executable(app main.c extra.c)\n")
    runner(engine, events := []).run(Plan(ws, (COLCON,)))
    said = notes(events)
    assert "installing afresh what changed its CMake files" in said, said
    assert "building msgs afresh as well (rosidl's generated code)" in said, said


def test_a_firmware_build_whose_container_was_killed_says_so_not_fix_the_firmware(ws):
    project = ws.root / "fw/cam_fw"
    (project / "main").mkdir(parents=True)
    (project / "package.xml").write_text("<package><name>cam_fw</name></package>\n")
    engine = FakeEngine(run_script=lambda spec, on_line: 137)
    with pytest.raises(BuildFailed) as failed:
        runner(engine, []).run(Plan(ws, (IdfBuild("cam_fw", "fw/cam_fw", "i", "esp32", "k"),)))
    assert "idf.py build of cam_fw was killed (exit code 137, SIGKILL)" in failed.value.message
    assert "OOM killer" in failed.value.hint and "Fix the firmware" not in failed.value.hint


@pytest.mark.parametrize(
    ("said", "hint"),
    [
        # An app moved from upstream's layout: the component was cloned into components/, not named.
        (
            "  Failed to resolve component 'micro_ros_espidf_component'.",
            "`list(APPEND EXTRA_COMPONENT_DIRS $ENV{UROS_COMPONENT_DIR})`",
        ),
        # A host path in the CMakeLists (CMake wraps the path onto the next line where it is long).
        ("  Directory specified in EXTRA_COMPONENT_DIRS doesn't exist:", "not the host's other paths"),
    ],
)
def test_a_firmware_build_failing_on_a_project_set_up_for_plain_idf_py_says_what_to_change(ws, said, hint):
    """An idf.py project brought in as it was: the build failed on IDF's words and said only "Fix
    the firmware"."""
    project = ws.root / "fw/cam_fw"
    (project / "main").mkdir(parents=True)
    (project / "package.xml").write_text("<package><name>cam_fw</name></package>\n")
    lines = ("CMake Error at /opt/esp/idf/tools/cmake/build.cmake:300 (message):", said, "-- Configuring incomplete")

    def idf_py(spec, on_line):
        for line in lines:
            on_line(line)
        return 2

    with pytest.raises(BuildFailed) as failed:
        runner(FakeEngine(run_script=idf_py), []).run(Plan(ws, (IdfBuild("cam_fw", "fw/cam_fw", "i", "esp32", "k"),)))
    assert hint in failed.value.hint and "installed firmware was left as it was" in failed.value.hint


def test_a_firmware_build_that_failed_on_the_engine_s_full_disk_names_that_disk(ws, tmp_path, monkeypatch):
    """The engine's data root full: espdock's own with-ca.sh failed writing its CA bundle in the
    container's /tmp ("cat: write error: No space left on device"), and the build said "Fix the
    firmware", exit 5, where a full disk is exit 7 naming it."""
    from espdock.build import runner as runner_module
    from espdock.errors import DiskFull, disk_full

    project = ws.root / "fw/cam_fw"
    (project / "main").mkdir(parents=True)
    (project / "package.xml").write_text("<package><name>cam_fw</name></package>\n")
    data_root = tmp_path / "var-lib-docker"
    data_root.mkdir()
    monkeypatch.setattr(
        runner_module, "disk_full", lambda path, **kw: disk_full(path, known=True) if path == data_root else None
    )
    engine = FakeEngine(run_script=lambda spec, on_line: 1, root=str(data_root))
    with pytest.raises(DiskFull) as full:
        runner(engine, []).run(Plan(ws, (IdfBuild("cam_fw", "fw/cam_fw", "i", "esp32", "k"),)))
    assert f"the disk holding {data_root}" in full.value.message and full.value.exit_code == 7


def test_flash_after_a_one_off_target_runs_in_that_chip_s_image(ws):
    """`espdock build fw --target esp32s3`, then `espdock flash fw`: flash built the micro-ROS image
    of the workspace's chip (offline: exit 4, nothing written) for firmware built for another."""
    project = ws.root / "fw/cam_fw"
    (project / "main").mkdir(parents=True)
    (project / "package.xml").write_text("<package><name>cam_fw</name></package>\n")
    marker = ws.ws_dir / "build/cam_fw/.espdock-target"
    marker.parent.mkdir(parents=True)
    marker.write_text("esp32s3\n\n5ebe61ea41404df8\n")
    s3 = "espdock/idf-micro-ros-jazzy-esp32s3:5ebe61ea41404df8"
    engine = FakeEngine({s3: ImageInfo("id", (s3,), datetime.now(UTC), 1, {})})
    step = IdfBuild("cam_fw", "fw/cam_fw", "espdock/idf-micro-ros-jazzy-esp32:4cb1078bd25db399", "esp32", "4cb10")
    built, current = runner(engine, []).firmware.installed_from(ws, step)
    assert (built.image, built.target, current) == (s3, "esp32s3", False)


def test_firmware_a_one_off_target_built_is_current_until_its_sources_change(ws):
    """`espdock build fw --target esp32s3`, then `espdock flash fw`: flash called the firmware just
    built stale (its stamp was compared with the workspace chip's) and offered `espdock build fw`,
    which would have replaced it with the other chip's."""
    project = ws.root / "fw/cam_fw"
    (project / "main").mkdir(parents=True)
    (project / "package.xml").write_text("<package><name>cam_fw</name></package>\n")
    (project / "main/app.c").write_text("void app_main(void) {}\n")
    s3 = "espdock/idf-micro-ros-jazzy-esp32s3:5ebe61ea41404df8"
    esp32 = "espdock/idf-micro-ros-jazzy-esp32:4cb1078bd25db399"
    now = datetime.now(UTC)
    engine = FakeEngine({s3: ImageInfo("s3-id", (s3,), now, 1, {}), esp32: ImageInfo("id", (esp32,), now, 1, {})})
    one_off = IdfBuild("cam_fw", "fw/cam_fw", s3, "esp32s3", "5ebe61ea41404df8")
    runner(engine, []).run(Plan(ws, (one_off,)))
    step = IdfBuild("cam_fw", "fw/cam_fw", esp32, "esp32", "4cb1078bd25db399")
    built, current = runner(engine, []).firmware.installed_from(ws, step)
    assert (built.image, built.target, current) == (s3, "esp32s3", True)
    (project / "main/app.c").write_text("void app_main(void) { for (;;); }\n")
    assert runner(engine, []).firmware.installed_from(ws, step)[1] is False
    # Built for the workspace's chip, then an interface it depends on edited (a new micro-ROS key,
    # the old image still there): stale, as its sources build another firmware now.
    runner(engine, []).run(Plan(ws, (step,)))
    assert runner(engine, []).firmware.installed_from(ws, step)[1] is True
    edited = replace(step, image="espdock/idf-micro-ros-jazzy-esp32:0123456789abcdef", image_key="0123456789abcdef")
    engine.images_by_tag[edited.image] = ImageInfo("new-id", (edited.image,), now, 1, {})
    built, current = runner(engine, []).firmware.installed_from(ws, edited)
    assert (built.image, current) == (esp32, False)
