"""The runner against FakeEngine: cache hits and misses, colcon failures, no-op builds, events."""

from __future__ import annotations

import os
from datetime import UTC, datetime
from pathlib import Path

import pytest

from espdock import bootstrap
from espdock.config import Config
from espdock.engine import ImageInfo
from espdock.errors import BuildFailed
from espdock.events import Outcome, StepFinished, StepNote
from espdock.plan import ColconBuild, EnsureImage, Plan, ros_build_image
from espdock.runner import Runner
from espdock.workspace import Workspace
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


def colcon_installs(ws: Workspace, code: int = 0, lines: tuple[str, ...] = ()):
    def play(spec, on_line):
        for line in lines:
            on_line(line)
        if code == 0:
            for name in ("msgs", "app"):
                (ws.ws_dir / "install" / name).mkdir(parents=True, exist_ok=True)
                (ws.ws_dir / "install" / name / "marker").write_text(name)
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


def test_the_colcon_container_runs_as_the_owner_in_the_colcon_root(ws):
    engine = FakeEngine(run_script=colcon_installs(ws))
    runner(engine, []).run(Plan(ws, (COLCON,)))
    (spec,) = engine.runs
    assert spec.user == f"{os.getuid()}:{os.getgid()}"
    assert [(m.source, m.target) for m in spec.mounts] == [(ws.root, "/workspace")]
    assert spec.workdir == "/workspace/ws"
    assert engine.removed == [{"io.espdock.workspace": str(Path(ws.root)), "io.espdock.step": "colcon"}]
