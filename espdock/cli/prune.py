"""`espdock prune`: remove the keyed images no workspace's inputs use any more, trim BuildKit's cache."""

from __future__ import annotations

import errno
import os
import time
from typing import Annotated

import typer
from rich.text import Text

from espdock.build.prepare import current_tags
from espdock.build.runner import Runner
from espdock.build.steps import LABEL_KEY
from espdock.cli.core import WorkspaceOption, app, command, console, load, notify
from espdock.config import Config
from espdock.errors import EspdockError, WorkspaceError
from espdock.images import bootstrap
from espdock.images import volume as workspace_volume
from espdock.images.engine import Engine
from espdock.images.prune import (
    GB,
    has_record,
    images_total,
    prune_images,
    read_records,
    record_use,
    size_text,
    state_dir,
    trim_cache,
)
from espdock.ros.plan import runtime_repository
from espdock.workspace import Workspace, workspace_gone, workspace_lock


def remove_volumes(engine: Engine, ws: Workspace, dry_run: bool) -> None:
    """`espdock prune --volume`: the workspace's volumes on the engine (espdock.volume)."""
    names = engine.volumes(workspace_volume.volume_labels(ws))
    verb = "would remove" if dry_run else "removed"
    with workspace_lock(ws):
        for name in names:
            if not dry_run:
                engine.remove_volume(name)
            console.print(Text(f"{verb} volume {name}"))
        if not dry_run:
            workspace_volume.forget(ws)
    if not names:
        console.print(Text(f"no volume of {ws.root} on this engine"))


@app.command()
@command
def prune(
    keep: Annotated[
        int | None,
        typer.Option("--keep", min=0, help="Generations of each kind kept besides those in use (prune_keep)."),
    ] = None,
    all_workspaces: Annotated[
        bool,
        typer.Option(
            "--all-workspaces",
            help="Prune every workspace built on this machine, not just this one; "
            "those since removed lose all their images.",
        ),
    ] = False,
    dry_run: Annotated[bool, typer.Option("--dry-run", help="Say what would go and how much, remove nothing.")] = False,
    cache_max_gb: Annotated[
        float | None,
        typer.Option("--cache-max-gb", min=0, help="Trim BuildKit's cache to this many GB (build_cache_max_gb)."),
    ] = None,
    volume: Annotated[
        bool,
        typer.Option(
            "--volume",
            help="Remove only the workspace's volume on the engine (workspace_mode volume): its build dirs go; "
            "the next build with anything to build sends every source and builds every package.",
        ),
    ] = False,
    workspace: WorkspaceOption = None,
) -> None:
    """Remove this workspace's keyed images its current inputs no longer use, keeping the last few of
    each kind; never an image the last build of another workspace still there used or a running container needs."""
    try:
        ws, config = load(workspace)
    except WorkspaceError:
        # The clean-up after a user's workspaces were removed: from anywhere, with the defaults.
        if not all_workspaces or volume or workspace is not None:
            raise
        ws, config = None, Config()
    engine = bootstrap.ensure_engine(os.environ, notify)
    if volume:
        remove_volumes(engine, ws, dry_run)
        return
    keep = config.prune_keep if keep is None else keep
    layers_before = None if dry_run else engine.layers_size()
    current = current_tags(ws, config, env=os.environ) if ws is not None else set()
    root = str(ws.root) if ws is not None else ""
    state = state_dir(os.environ)
    if ws is not None and not all_workspaces and not has_record(state, ws.root):
        # Said, not a bare "0 images": a CI job whose HOME is new each time records nothing, and
        # its images pile up on a shared engine.
        notify(
            f"note: no build of {ws.root} recorded its images in {state} (each build does): nothing of this "
            "workspace's to prune here. Builds with another HOME or ESPDOCK_STATE_DIR (a CI job's fresh home) "
            "recorded theirs elsewhere: give them one ESPDOCK_STATE_DIR that lasts"
        )
    plan, busy = prune_images(engine, state, root, current, keep, all_workspaces, dry_run)
    layers_after = None if dry_run else engine.layers_size()
    verb = "would remove" if dry_run else "removed"
    for decision in plan.remove:
        if decision.tag in busy:
            console.print(Text(f"kept {decision.tag}: a container made since the plan uses it"))
        else:
            console.print(Text(f"{verb} {decision.tag} ({size_text(decision.size)}; {decision.reason})"))
    for decision in plan.keep:
        console.print(Text(f"kept {decision.tag} ({decision.reason})", style="dim"))
    if plan.gone_elsewhere:
        shown = ", ".join(plan.gone_elsewhere[:3]) + (", ..." if len(plan.gone_elsewhere) > 3 else "")
        console.print(
            Text(f"{len(plan.gone_elsewhere)} workspace(s) built here are gone ({shown}): ")
            + Text("espdock prune --all-workspaces", style="bold")
            + Text(" removes their images")
        )
    freed = sum(d.size for d in plan.remove if d.tag not in busy)
    bound = config.build_cache_max_gb if cache_max_gb is None else cache_max_gb
    cache, trimmed = trim_cache(engine, bound, dry_run)
    cache_text = "size unknown (the engine was busy reporting it)" if cache is None else size_text(cache)
    would_trim = dry_run and cache is not None and cache > bound * GB
    if trimmed or would_trim:
        # Trimming to make room for one workspace takes the other workspaces' cache as well.
        done = f"{size_text(trimmed)} trimmed" if trimmed else f"would be trimmed to {size_text(int(bound * GB))}"
        cache_text += f", {done} (the engine's one cache: every workspace's and user's builds)"
    # Each image's own bytes: layers the removed images share only among themselves come on top,
    # which the engine's whole layer store, before and after, shows.
    disk = ""
    if layers_before is not None and layers_after is not None:
        disk = f" (the engine's image layers: {size_text(layers_before)} -> {size_text(layers_after)})"
    amount = f"at least {size_text(freed)}{disk}"
    if engine.info().kind == "podman":
        # Its Docker API reports no layer an image shares (each image's whole size looked its own:
        # "at least 819.64 MB" where 0.5 MB went) and no layers' total (0 B -> 0 B).
        amount = "how much they freed unknown (Podman does not say what its images share: `podman system df`)"
    console.print(f"{verb} {len(plan.remove) - len(busy)} images, {amount}; BuildKit cache {cache_text}")


def record_images(ws: Workspace, runner: Runner, runtime: str | None = None, whole: bool = True) -> None:
    """Record the keyed images RUNNER used for WS (a build's, `run`'s, `espdock test`'s): what
    `espdock prune` may remove later. RUNTIME: the workspace's runtime image repository, which
    another workspace of the same name shares (said once it is used). WHOLE: not a build of some
    packages only (record_use)."""
    state = state_dir(os.environ)
    try:
        record_use(state, ws.root, runner.used_images, time.time(), whole)
    except OSError as exc:
        # Named by the file: one of root's (a run as root with this HOME) is mended by a chown.
        where = exc.filename or state
        notify(
            f"warning: could not record the images this command used in {where}: {exc.strerror}; `espdock prune` "
            "may remove them while this workspace still uses them"
            + (f" (`sudo chown -R $(id -u):$(id -g) {state}` makes it yours)" if exc.errno == errno.EACCES else "")
        )
    if runtime is None or all(repository != runtime for _, repository in runner.used_images):
        return
    others = [
        record.root
        for record in read_records(state)
        if record.root != str(ws.root)
        and any(image.repository == runtime for image in record.images)
        and not workspace_gone(record.root)
    ]
    if others:
        # Not why: the same `name` setting (a clone's espdock.toml) or directories of one name. Nor
        # the compose project's name, which is Compose's (the file's `name:`, COMPOSE_PROJECT_NAME).
        notify(
            f"warning: {others[0]} names its runtime images {runtime}:latest too: `docker compose` in either "
            "runs the one built last, and where both run one compose project (as a clone's compose file does), "
            "each one's replaces the other's containers; set name = \"...\" in one's espdock.toml to tell them "
            "apart (or ESPDOCK_NAME=... in its environment, for a git worktree or clone sharing the file)"
        )


def after_build(engine: Engine, ws: Workspace, config: Config, runner: Runner, built: bool, whole: bool = True) -> None:
    """Record the images the build used (WHOLE: record_use); prune when prune_auto; when the build
    BUILT something, say once when espdock's images take more than images_warn_gb. A build that
    changed nothing added no image: listing them all costs the engine more than the rest of such a build."""
    record_images(ws, runner, runtime_repository(config, ws), whole)
    try:
        _prune_or_warn(engine, ws, config, built)
    except EspdockError as exc:  # the build succeeded: what is only housekeeping must not fail it
        notify(f"warning: {exc.message}")


def _prune_or_warn(engine: Engine, ws: Workspace, config: Config, built: bool) -> None:
    if config.prune_auto:
        current = current_tags(ws, config, env=os.environ)
        plan, busy = prune_images(engine, state_dir(os.environ), str(ws.root), current, config.prune_keep, False, False)
        if plan.remove:
            freed = sum(d.size for d in plan.remove if d.tag not in busy)
            notify(f"prune_auto: removed {len(plan.remove) - len(busy)} images no longer used ({size_text(freed)})")
        trim_cache(engine, config.build_cache_max_gb, False)
    if not built:
        return
    total = images_total(engine.labelled_images(LABEL_KEY))
    if total > config.images_warn_gb * GB:
        # Each image's size counts the layers it shares with the others again (44.5 GB said where
        # the engine's images took 3 GB): the engine's whole layer store bounds it too.
        total = min(total, engine.layers_size() or total)
    if total > config.images_warn_gb * GB:
        auto = "" if config.prune_auto else " (prune_auto = true in espdock.toml does it after each build)"
        console.print(
            Text(
                f"note: espdock's images on this engine take up to {size_text(total)} (more than "
                f"images_warn_gb = {config.images_warn_gb:g}); `espdock prune --dry-run` shows what "
                f"`espdock prune` would remove{auto}",
                style="yellow",
            )
        )
