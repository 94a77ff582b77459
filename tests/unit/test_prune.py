"""espdock.images.prune's pure parts: the per-workspace records and which images a prune removes."""

from __future__ import annotations

import shutil

from espdock.images.prune import Present, Record, UsedImage, forgettable, plan_prune, read_records, record_use


def test_a_build_records_its_images_as_current_per_kind(tmp_path):
    record_use(tmp_path, tmp_path / "ws", [("espdock/ros:a1", "espdock/ros"), ("espdock/w:b1", "espdock/w")], 10)
    record_use(tmp_path, tmp_path / "ws", [("espdock/ros:a2", "espdock/ros")], 20)  # a build of one kind
    (record,) = read_records(tmp_path)
    assert record.root == str(tmp_path / "ws")
    assert record.current == {"espdock/ros:a2", "espdock/w:b1"}
    assert {(i.tag, i.used) for i in record.images} == {("espdock/ros:a1", 10), ("espdock/ros:a2", 20),
                                                         ("espdock/w:b1", 10)}  # fmt: skip


def test_a_build_of_some_packages_keeps_the_other_current_images_of_the_kinds_it_used(tmp_path):
    """Two firmware packages with micro-ROS images of one chip (their library inputs differ):
    `espdock build board_a` recorded only board_a's as current, and another workspace's prune then
    removed board_b's as "no longer used by its inputs", which the next build here built again."""
    uros = "espdock/idf-micro-ros-jazzy-esp32"
    ws = tmp_path / "ws"
    record_use(tmp_path, ws, [(f"{uros}:a1", uros), (f"{uros}:b1", uros), ("espdock/ros:r1", "espdock/ros")], 10)
    record_use(tmp_path, ws, [(f"{uros}:a2", uros)], 20, whole=False)  # board_a edited and built alone
    (record,) = read_records(tmp_path)
    assert {f"{uros}:b1", f"{uros}:a2", "espdock/ros:r1"} <= record.current
    # Another workspace's prune, which reads this record: board_b's image stays.
    plan = plan_prune([record], {"/elsewhere"}, {}, present(f"{uros}:b1"), set(), keep=0)
    assert plan.remove == ()
    record_use(tmp_path, ws, [(f"{uros}:a2", uros), (f"{uros}:b2", uros)], 30)  # a whole build: these only
    (record,) = read_records(tmp_path)
    assert {t for t in record.current if t.startswith(uros)} == {f"{uros}:a2", f"{uros}:b2"}


def generations(root: str, kind: str, count: int) -> tuple[UsedImage, ...]:
    return tuple(UsedImage(f"{kind}:{n}", kind, float(n)) for n in range(1, count + 1))


def present(*tags: str) -> list[Present]:
    return [Present(tag, f"id-{tag}", 100) for tag in tags]


def test_the_old_generations_go_the_last_n_and_what_others_or_containers_use_stay():
    ours = Record("/a", generations("/a", "ros", 5), frozenset({"ros:5"}))
    theirs = Record("/b", (UsedImage("ros:2", "ros", 2.0),), frozenset({"ros:2"}))
    tags = [f"ros:{n}" for n in range(1, 6)]
    plan = plan_prune([ours, theirs], {"/a"}, {"/a": {"ros:5"}}, present(*tags), {"id-ros:1": (True, "node")}, keep=1)
    assert [d.tag for d in plan.remove] == ["ros:3"]
    assert {d.tag: d.reason for d in plan.keep} == {
        "ros:4": "one of the last 1 of its kind",
        "ros:2": "another workspace's last build used it",
        "ros:1": "a running container uses it",
        "ros:5": "used by the current inputs",
    }
    assert plan.freed == 100


def test_what_the_inputs_use_now_stays_though_no_build_recorded_it_and_gone_images_are_skipped():
    ours = Record("/a", generations("/a", "ros", 3), frozenset({"ros:3"}))
    plan = plan_prune([ours], {"/a"}, {"/a": {"ros:1"}}, present("ros:1", "ros:3"), set(), keep=1)
    assert plan.remove == ()  # ros:2 is no longer on the engine, ros:1 is what the inputs use now


def test_a_kind_the_inputs_no_longer_use_is_not_kept_as_current_because_the_last_build_used_it():
    """A chip whose last firmware package went (or a one-off --target build): its micro-ROS image
    stayed "used by the current inputs" for ever, as the record keeps the current image of each
    kind a build did not touch."""
    ours = Record("/a", (UsedImage("ros:1", "ros", 1.0), UsedImage("s3:1", "s3", 1.0)), frozenset({"ros:1", "s3:1"}))
    plan = plan_prune([ours], {"/a"}, {"/a": {"ros:1"}}, present("ros:1", "s3:1"), set(), keep=0)
    assert [(d.tag, d.reason) for d in plan.remove] == [("s3:1", "no longer used by its inputs")]
    # Another workspace's record, whose current inputs no one computed, still speaks for it.
    theirs = Record("/b", (UsedImage("s3:1", "s3", 1.0),), frozenset({"s3:1"}))
    assert plan_prune([ours, theirs], {"/a", "/b"}, {"/a": {"ros:1"}}, present("ros:1", "s3:1"), set(), 0).remove == ()


def test_a_tag_whose_image_keeps_another_tag_frees_nothing_and_says_so():
    """The runtime image of a workspace's former name (ESPDOCK_NAME, a renamed directory) keeps
    its `:latest`: prune said "removed espdock/old:k1 (475 kB ...)" and the image stayed."""
    ours = Record("/a", generations("/a", "espdock/old", 2), frozenset({"espdock/old:2"}))
    both_tags = [Present("espdock/old:1", "id-1", 500), Present("espdock/old:latest", "id-1", 500)]
    plan = plan_prune([ours], {"/a"}, {"/a": set()}, [*both_tags, *present("espdock/old:2")], {}, keep=0)
    decisions = {d.tag: d for d in plan.remove}
    assert decisions["espdock/old:1"].size == 0, decisions
    assert "its image stays, tagged espdock/old:latest" in decisions["espdock/old:1"].reason
    assert decisions["espdock/old:2"].size == 100  # its only tag goes: its bytes do


def test_the_latest_of_a_name_nothing_stays_of_goes_with_its_last_image():
    """`espdock/<name>:latest` of a removed workspace, or of a workspace's former name: no build
    makes it again, and prune left it, with its image, for ever (its record forgotten)."""
    removed = Record("/gone", generations("/gone", "espdock/gone", 1), frozenset({"espdock/gone:1"}))
    renamed = Record(
        "/a", (*generations("/a", "espdock/old", 1), *generations("/a", "espdock/new", 1)), frozenset({"espdock/new:1"})
    )
    on_engine = [
        Present("espdock/gone:1", "id-g", 300),
        Present("espdock/gone:latest", "id-g", 300),
        Present("espdock/old:1", "id-o", 200),
        Present("espdock/old:latest", "id-o", 200),
        Present("espdock/new:1", "id-n", 100),
        Present("espdock/new:latest", "id-n", 100),
    ]
    plan = plan_prune([removed, renamed], {"/gone", "/a"}, {}, on_engine, {}, keep=0, gone={"/gone"})
    sizes = {d.tag: d.size for d in plan.remove}
    assert sizes == {"espdock/gone:1": 300, "espdock/gone:latest": 0, "espdock/old:1": 200, "espdock/old:latest": 0}
    # The name a live workspace's last build used keeps its :latest (plain `docker compose` runs it).
    assert "espdock/new:latest" not in sizes


def test_only_the_targets_are_pruned_and_unrecorded_images_never():
    ours = Record("/a", generations("/a", "ros", 2), frozenset({"ros:2"}))
    theirs = Record("/b", generations("/b", "w", 2), frozenset({"w:2"}))
    everything = present("ros:1", "ros:2", "w:1", "w:2", "debian:bookworm-slim", "someone/else:1")
    assert [d.tag for d in plan_prune([ours, theirs], {"/a"}, {}, everything, set(), 0).remove] == ["ros:1"]
    both = plan_prune([ours, theirs], {"/a", "/b"}, {}, everything, set(), 0)
    assert sorted(d.tag for d in both.remove) == ["ros:1", "w:1"]
    # An image both targets' inputs use (the shared build image) is kept once, not once a workspace.
    shared = plan_prune([ours, theirs], {"/a", "/b"}, {"/a": {"ros:2"}, "/b": {"ros:2"}}, everything, set(), 0)
    assert [d.tag for d in shared.keep].count("ros:2") == 1
    # Kept for the strongest of its reasons, whichever record is read first (their file names are
    # hashes of the roots, so the order differs from machine to machine).
    theirs_uses_ours = Record("/b", generations("/b", "w", 2), frozenset({"w:2", "ros:1"}))
    for records in ([ours, theirs_uses_ours], [theirs_uses_ours, ours]):
        plan = plan_prune(records, {"/a", "/b"}, {"/b": {"ros:1"}}, everything, set(), 0)
        assert {d.tag: d.reason for d in plan.keep}["ros:1"] == "used by the current inputs"


def test_a_removed_workspace_protects_nothing_and_its_images_go_with_every_workspace():
    ours = Record("/a", generations("/a", "ros", 3), frozenset({"ros:3"}))
    removed = Record("/b", (*generations("/b", "ros", 2), *generations("/b", "w", 2)), frozenset({"ros:2", "w:2"}))
    everything = present("ros:1", "ros:2", "ros:3", "w:1", "w:2")
    # ros:2, which the removed workspace's last build used, no longer stays for it.
    alone = plan_prune([ours, removed], {"/a"}, {"/a": {"ros:3"}}, everything, set(), 0, gone={"/b"})
    assert sorted(d.tag for d in alone.remove) == ["ros:1", "ros:2"]
    assert alone.gone_elsewhere == ("/b",)
    # With every workspace: all of its images go, its last build's and the last N alike, but for
    # ros:2, one of the last 1 of the live workspace's.
    every = plan_prune([ours, removed], {"/a", "/b"}, {"/a": {"ros:3"}}, everything, set(), 1, gone={"/b"})
    assert [d.tag for d in every.remove].count("ros:1") == 1  # both recorded it
    assert {d.tag: d.reason for d in every.remove} == {
        "ros:1": "no longer used by its inputs",  # the live workspace's decision, made first
        "w:1": "its workspace is gone",
        "w:2": "its workspace is gone",
    }
    assert {d.tag: d.reason for d in every.keep} == {
        "ros:2": "one of the last 1 of its kind",
        "ros:3": "used by the current inputs",
    }
    assert every.gone_elsewhere == ()
    # Its record goes once what is left of its images is the live workspace's: kept for it (ros:2),
    # the record stayed, and every later prune said to prune --all-workspaces, which removed nothing.
    assert forgettable([ours, removed], {"/b"}, {"ros:2", "ros:3"}) == ["/b"]
    assert forgettable([ours, removed], {"/b"}, {"ros:3", "w:2"}) == [], "w:2 is its own: kept, a container uses it"
    kept_for_ours = plan_prune([ours, removed], {"/a"}, {"/a": {"ros:3"}}, present("ros:2", "ros:3"), set(), 0, {"/b"})
    assert kept_for_ours.gone_elsewhere == (), "nothing of its own left for --all-workspaces to remove"


def test_a_second_workspace_of_the_same_name_is_told_to_set_its_own(tmp_path, monkeypatch, capsys):
    """Two clones called robot: both made espdock/robot:latest and compose project robot, so plain
    `docker compose up` in one ran the other's nodes, and one's compose replaced the other's."""
    from types import SimpleNamespace

    from espdock.cli.prune import record_images
    from espdock.workspace import Workspace

    monkeypatch.setenv("ESPDOCK_STATE_DIR", str(tmp_path / "state"))
    first, second = tmp_path / "main/robot", tmp_path / "feature/robot"
    for root in (first, second):
        root.mkdir(parents=True)
    runtime = SimpleNamespace(used_images=[("espdock/robot:0123456789abcdef", "espdock/robot")])
    record_images(Workspace(first), runtime, "espdock/robot")
    record_images(Workspace(first), runtime, "espdock/robot")
    assert "names its runtime images" not in capsys.readouterr().out
    keyed = SimpleNamespace(used_images=[("espdock/ros-jazzy-build:0123456789abcdef", "espdock/ros-jazzy-build")])
    record_images(Workspace(second), keyed, "espdock/robot")
    assert "names its runtime images" not in capsys.readouterr().out, "shared keyed images are no clash"
    record_images(Workspace(second), runtime, "espdock/robot")
    err = " ".join(capsys.readouterr().out.split())
    assert f"{first} names its runtime images espdock/robot:latest too" in err
    assert 'set name = "..." in one\'s espdock.toml' in err and "ESPDOCK_NAME=... in its environment" in err
    # Nor a cause it cannot know: two clones named by `name = "robot"` in directories called otherwise were
    # told their directories shared a name, and that their compose projects were "robot" (Compose's say).
    assert "its directory has" not in err and "compose projects (robot)" not in err, err


def test_the_runtime_images_run_uses_are_current_where_builds_make_none(tmp_path):
    """With runtime_image off, `espdock run` makes the runtime image (and its base, minutes to
    build): once prune took only what the inputs use now, it counted neither as in use."""
    from espdock.build.prepare import current_tags
    from espdock.config import Config
    from espdock.workspace import find_workspace
    from tests.conftest import copy_workspace

    root = copy_workspace(tmp_path / "w", runtime_image=False)
    ws = find_workspace(root).with_layout(("ws/src",), "ws")
    tags = current_tags(ws, Config(runtime_image=False), env={})
    assert any(tag.startswith("espdock/ros-jazzy-runtime:") for tag in tags), tags


def test_the_image_a_board_s_installed_firmware_was_built_in_stays_current(tmp_path):
    """An interface edited and one board rebuilt: prune removed the image the other board's
    installed firmware was built in, and its `flash` then built a library of the half-edited
    interface (and failed on it)."""
    from espdock.build.prepare import current_tags
    from espdock.config import Config
    from espdock.workspace import find_workspace
    from tests.conftest import REPO, copy_workspace

    root = copy_workspace(tmp_path / "w", runtime_image=False)
    shutil.copytree(REPO / "firmware", root / "firmware")
    shutil.copy2(REPO / "Dockerfile.idf", root / "Dockerfile.idf")
    ws = find_workspace(root).with_layout(("ws/src", "firmware"), "ws")
    before = current_tags(ws, Config(runtime_image=False), env={})
    marker = root / "ws/build/camera_node/.espdock-target"
    marker.parent.mkdir(parents=True)
    marker.write_text("esp32\n\n0123456789abcdef\n")  # built in the image of an older interface
    tags = current_tags(ws, Config(runtime_image=False), env={})
    assert tags - before == {"espdock/idf-micro-ros-jazzy-esp32:0123456789abcdef"}, tags - before
    marker.write_text("esp32s3\n\n0123456789abcdef\n")  # a one-off `--target esp32s3` built it
    tags = current_tags(ws, Config(runtime_image=False), env={})
    assert tags - before == {"espdock/idf-micro-ros-jazzy-esp32s3:0123456789abcdef"}, tags - before


def test_two_commands_recording_at_once_lose_neither_s_images(tmp_path):
    """Two `espdock run`s (or a build and a compose up) of one workspace at once: each read the
    record, added its images and wrote it back, and the one that wrote last dropped the other's.
    A prune from another workspace then took an image this one had just used for one of its own."""
    import subprocess
    import sys

    script = (
        "import sys; from pathlib import Path; from espdock.images.prune import record_use\n"
        "state, ws, kind = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]\n"
        "for n in range(150):\n"
        "    record_use(state, ws, [(f'{kind}:{n}', kind)], n, whole=False)\n"
    )
    kinds = ("espdock/ros-a", "espdock/ros-b")
    writers = [
        subprocess.Popen([sys.executable, "-c", script, str(tmp_path), str(tmp_path / "ws"), kind]) for kind in kinds
    ]
    assert [writer.wait(timeout=120) for writer in writers] == [0, 0]
    (record,) = read_records(tmp_path)
    recorded = {image.tag for image in record.images}
    lost = sorted({f"{kind}:{n}" for kind in kinds for n in range(150)} - recorded)
    assert not lost, f"{len(lost)} recorded uses lost, e.g. {lost[:3]}"


def test_the_size_note_after_a_build_counts_shared_layers_once_at_most(capsys):
    """Each image's size counts the layers it shares again: a build said espdock's images took up
    to 44.52 GB where the engine's images took 2.99 GB, and pointed at a prune that freed 123 kB."""
    from types import SimpleNamespace

    from espdock.cli.prune import _prune_or_warn
    from espdock.config import Config

    listing = [(f"id{n}", (f"espdock/ros:{n}",), 10**6, 4 * 10**9) for n in range(10)]  # 40 GB, counted so
    engine = SimpleNamespace(labelled_images=lambda label: listing, layers_size=lambda: 3 * 10**9)
    _prune_or_warn(engine, None, Config(images_warn_gb=2), built=True)
    said = " ".join(capsys.readouterr().out.split())
    assert "take up to 3.00 GB (more than images_warn_gb = 2)" in said, said
    _prune_or_warn(engine, None, Config(images_warn_gb=5), built=True)
    assert "take up to" not in capsys.readouterr().out


def test_a_record_that_cannot_be_written_is_named_with_what_it_costs(tmp_path, monkeypatch, capsys):
    """A root-owned record (a run as root with the user's HOME): "could not record ... in
    ~/.local/state/espdock: Permission denied", naming neither the file nor what follows."""
    from types import SimpleNamespace

    from espdock.cli.prune import record_images
    from espdock.workspace import Workspace

    monkeypatch.setenv("ESPDOCK_STATE_DIR", str(tmp_path / "state"))
    (tmp_path / "state").mkdir()
    (tmp_path / "state/workspaces").write_text("not a directory\n")
    (tmp_path / "ws").mkdir()
    runner = SimpleNamespace(used_images=[("espdock/ros:0123456789abcdef", "espdock/ros")])
    record_images(Workspace(tmp_path / "ws"), runner, None)
    said = " ".join(capsys.readouterr().out.split())
    assert f"could not record the images this command used in {tmp_path / 'state/workspaces'}" in said, said
    assert "`espdock prune` may remove them while this workspace still uses them" in said, said
