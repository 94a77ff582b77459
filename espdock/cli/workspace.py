"""The workspace commands: build, lock, verify, new, init, setup, list."""

from __future__ import annotations

import contextlib
import os
import shlex
import time
from pathlib import Path
from typing import Annotated

import typer
from rich.text import Text

from espdock.build.lock import FIX, check_locks, lock_rosdeps, lock_workspace, plan_locks, stale_locks, uv_binary
from espdock.build.manifest import INTERRUPTED, compare, file_hashes, read_manifest, record_build, write_report
from espdock.build.prepare import check_only, workspace_packages
from espdock.build.preview import preview
from espdock.build.runner import Runner, stamp_files
from espdock.cli import complete
from espdock.cli.core import (
    PASSED,
    PassThrough,
    WorkspaceOption,
    app,
    build_plan,
    command,
    console,
    err_console,
    load,
    notify,
    say,
)
from espdock.cli.nodes import stale_runtime_note
from espdock.cli.prune import after_build, record_images
from espdock.cli.ui import STAMPED, Reporter, nothing_to_build, render_packages, render_plan
from espdock.config import check_target, in_ci, invoking_user, no_cache_registry, resolve_ca_bundle
from espdock.errors import ConfigError, EspdockError, WorkspaceError
from espdock.events import Outcome
from espdock.firmware import transport
from espdock.firmware.plan import declared_chips
from espdock.firmware.scaffold import (
    GITIGNORE,
    check_new_package,
    create_firmware_package,
    init_workspace,
    undo_init,
    unignored_outputs,
)
from espdock.images import bootstrap
from espdock.images.containers import prepare_output
from espdock.images.keyed import unpushed_error
from espdock.layout import ROSDEP_LOCK
from espdock.ros import colcon_register, rosdeps
from espdock.ros.compose import NAME_VARIABLE, init_compose, plain_compose_note
from espdock.ros.plan import ColconBuild, base_image, runtime_repository
from espdock.ros.trees import orphan_installs, package_trees
from espdock.workspace import (
    PackageKind,
    build_running,
    check_not_building,
    current_dir,
    find_workspace,
    idf_project_cmake,
    read_build_inputs,
    search_warnings,
    unmanifested,
)


@app.command(cls=PassThrough)
@command
def build(
    ctx: typer.Context,
    packages: Annotated[
        list[str] | None,
        typer.Argument(help="Build only these packages and what they depend on.", autocompletion=complete.packages),
    ] = None,
    dry_run: Annotated[bool, typer.Option("--dry-run", help="Print the plan without running it.")] = False,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="Show image build logs in full.")] = False,
    timestamps: Annotated[
        bool, typer.Option("--timestamps", help="Start every output line with the UTC time (for CI logs).")
    ] = False,
    target: Annotated[
        str | None, typer.Option(help="Chip for the firmware packages built (overrides each one's own).")
    ] = None,
    only: Annotated[PackageKind | None, typer.Option(help="Build only the ROS packages or only the firmware.")] = None,
    force: Annotated[bool, typer.Option("--force", help="Build the packages even when nothing changed.")] = False,
    report: Annotated[
        Path | None, typer.Option("--report", help="Write a JSON summary (steps, outcome, keys, artefacts) here.")
    ] = None,
    locked: Annotated[
        bool | None,
        typer.Option(
            "--locked/--no-locked",
            help="Refuse to build when a lock the images use is missing or stale (default: on in CI, CI set).",
            show_default=False,
        ),
    ] = None,
    push_cache: Annotated[
        bool,
        typer.Option(
            "--push-cache", help="Push keyed images the cache registry lacks (cache_registry; CI on the main branch)."
        ),
    ] = False,
    runtime_image: Annotated[
        bool | None,
        typer.Option(
            "--runtime-image/--no-runtime-image",
            help="Also make the runtime image of install/, espdock/<name>:latest (default: the setting "
            "runtime_image, off: `espdock run` and `espdock compose` make it when they need it).",
            show_default=False,
        ),
    ] = None,
    workspace_mode: Annotated[
        str | None,
        typer.Option(
            "--workspace-mode",
            help="auto, mount or volume: how build containers get the workspace; volume keeps it in a volume on "
            "an engine that does not see this machine's files (setting workspace_mode, default auto).",
            show_default=False,
        ),
    ] = None,
    workspace: WorkspaceOption = None,
) -> None:
    """Build the images when their inputs changed, then every package whose sources changed and what
    depends on it; record what the build produced in install/espdock-manifest.json.

    Options after `--` go to `colcon build` (e.g. `espdock build -- --cmake-args -DBUILD_TESTING=OFF`)."""
    STAMPED["lines"] = timestamps
    ws, config = load(workspace, runtime_image=runtime_image, workspace_mode=workspace_mode)
    locked = locked if locked is not None else in_ci(os.environ)
    if not dry_run:
        check_not_building(ws)
    elif (holder := build_running(ws)) is not None:
        notify(f"note: an espdock build is running in {ws.root}{holder}: a build now is refused until it ends")
    started = time.monotonic()
    owner = invoking_user(os.environ, ws.root)
    if report is not None and not dry_run:
        prepare_output(report, owner, "--report")
    try:
        plan = build_plan(
            ws,
            config,
            packages or [],
            only,
            force,
            ctx.meta.get(PASSED),
            locked,
            target and check_target(target, "--target"),
            dry_run=dry_run,
        )
        if packages and only is not None:
            check_only(workspace_packages(ws, config.ros_distro), packages, only, plan, notify)
        if dry_run and locked:
            check_locks(ws.root, plan_locks(plan))  # as the build would refuse them
        elif not locked:
            # Not refreshed as the rosdep lock is (that needs PyPI): said, where a package added to
            # a .in was silently missing from the image built.
            for reason in stale_locks(ws.root, plan_locks(plan)):
                err_console.print(
                    Text.assemble(
                        ("warning: ", "yellow"),
                        f"{reason}: the images are built from it as it is; {FIX} to take the change in",
                    )
                )
        if dry_run:
            render_plan(
                console, plan, preview(ws, plan, bootstrap.reachable_engine(os.environ), bool(config.cache_registry))
            )
            return
        if not plan.steps:
            has_any = only is not None and workspace_packages(ws, config.ros_distro)
            console.print(f"nothing to build: no {only} package in the workspace" if has_any else nothing_to_build(ws))
            if report is not None:  # a CI job's artefact step expects one; an empty manifest: nothing built
                write_report(report, (), {}, time.monotonic() - started, owner)
            return
        if locked:
            check_locks(ws.root, plan_locks(plan))
        if push_cache and not config.cache_registry:
            raise no_cache_registry(os.environ)
        engine = bootstrap.ensure_engine(os.environ, notify)
    except EspdockError as exc:
        # A CI job keeps the report whatever stopped the build: a stale lock, no engine.
        if report is not None and not dry_run:
            write_report(report, (), None, time.monotonic() - started, owner, exc.message)
        raise
    reporter = Reporter(console, verbose=verbose, timestamps=timestamps)
    manifest: dict | None = None
    stopped: str | None = None  # what ended the build, for the report
    try:
        runner = Runner(engine, config, os.environ, reporter, owner, push_cache=push_cache)
        try:
            results = runner.run(plan)
        except BaseException:
            # The images a failed build made are its inputs' as they are: prune has to know them.
            record_images(ws, runner, whole=not packages)
            raise
        built = any(r.outcome is not Outcome.CACHED for r in results)
        chown = owner if os.geteuid() == 0 else None
        manifest = record_build(plan, config.target, ws.ws_dir / "install", built, stamp_files(ws), chown)
        if runner.unpushed:
            # Asked for, so a job that publishes the cache must not pass without it.
            after_build(engine, ws, config, runner, built, whole=not packages)
            raise unpushed_error(runner.unpushed, config.cache_registry, "The build itself succeeded and is installed")
    except KeyboardInterrupt:
        stopped = INTERRUPTED  # a cancelled CI job, not a failed build
        raise
    except EspdockError as exc:
        stopped = exc.message
        raise
    finally:
        reporter.close()
        reporter.summary()
        if report is not None:
            try:
                write_report(report, reporter.finished, manifest, time.monotonic() - started, owner, stopped)
            except OSError as exc:
                # Checked before the build, so something changed since; the build's outcome stands.
                unwritten = f"could not write the report {report}: {exc.strerror or exc}"
                if manifest is None:
                    say(Text.assemble(("warning: ", "yellow"), unwritten), err=True)
                else:
                    raise WorkspaceError(unwritten, "The build succeeded; its manifest is in install/.") from None
    found = workspace_packages(ws, config.ros_distro)  # as the build left them
    if orphans := orphan_installs(ws.ws_dir / "install", (p.name for p in found)):
        dirs = " ".join(rel for name in orphans for rel in package_trees(ws.ws_dir, name))
        say(
            Text(
                f"note: install/ holds {', '.join(orphans)}, of no package in this workspace any more (renamed or "
                f"removed?): colcon's setup scripts and ros2 run still find it; `rm -r {dirs}` in "
                f"{ws.ws_dir} removes it",
                style="yellow",
            )
        )
    colcon = {step.name for step in plan.steps if isinstance(step, ColconBuild)}
    if not config.runtime_image and any(r.step in colcon and r.outcome is not Outcome.CACHED for r in results):
        stale_runtime_note(engine, ws, config, plan, found)
    if config.runtime_image and (note := plain_compose_note(ws.root, runtime_repository(config, ws), os.environ)):
        # A worktree or clone of the committed file: its :latest is made, and plain Compose runs the original's.
        say(Text(note, style="yellow"))
    after_build(engine, ws, config, runner, built, whole=not packages)


@app.command()
@command
def lock(
    upgrade: Annotated[
        bool, typer.Option("--upgrade", help="Move every pin to the newest version its source allows.")
    ] = False,
    workspace: WorkspaceOption = None,
) -> None:
    """Compile every dependency lock of the workspace from its source with uv (pinned, with hashes),
    keeping the current pins the sources allow; say which locks changed."""
    ws, config = load(workspace)
    owner = invoking_user(os.environ, ws.root) if os.geteuid() == 0 else None
    packages = workspace_packages(ws, config.ros_distro)
    for result in lock_workspace(ws.root, uv_binary(), upgrade, owner, resolve_ca_bundle(config, os.environ)):
        spec = result.spec
        if result.status == "default":
            console.print(f"{spec.lock}: espdock's default (the workspace has no {spec.source} of its own)")
        else:
            console.print(f"{spec.lock}: {result.status} (from {', '.join(spec.inputs)})")
    # After the wheel locks, whose pins constrain (and whose digests are part of) the rosdep lock's.
    status, database, _ = lock_rosdeps(
        ws.root, config, packages, read_build_inputs(ws, packages), os.environ, owner, notify=console.print
    )
    if database:  # else: none needed, none there
        console.print(f"{ROSDEP_LOCK}: {status} ({database})")
        # Recorded, not refused: a build of a package that needs one is what refuses it.
        lock = rosdeps.read_lock((ws.root / ROSDEP_LOCK).read_bytes(), ROSDEP_LOCK)
        for key, why in rosdeps.unserved(lock):
            err_console.print(Text.assemble(("warning: ", "yellow"), f"{key}: {why}; a build needing it is refused"))


@app.command()
@command
def verify(
    manifest: Annotated[Path, typer.Argument(help="An espdock-manifest.json (install/ of the build it describes).")],
    install: Annotated[
        Path | None, typer.Option("--install", help="The install tree to check (default: the manifest's directory).")
    ] = None,
) -> None:
    """Compare an install tree with a build manifest: every missing, extra or changed file; exit 1 on any."""
    data = read_manifest(manifest)
    tree = install or manifest.parent
    if not tree.is_dir():
        # Every file "missing": a typo in the path looked like a wiped install.
        raise WorkspaceError(f"{tree} is no directory", "Give --install the install tree to check.")
    if data["files"] and not any(os.path.lexists(tree / path) for path in data["files"]):
        # A manifest downloaded from CI (a job's artefact) sits in no install tree: every file of the
        # directory it was saved in was listed as extra, and as a plain user another's unreadable files stopped it.
        # So did `--install` given the colcon root, not its install/: a thousand lines of build/ and log/.
        below = tree / "install"
        inner = below.is_dir() and any(os.path.lexists(below / path) for path in data["files"])
        raise WorkspaceError(
            f"{tree} holds none of the {len(data['files'])} files {manifest.name} lists: it is no install tree of it",
            f"Did you mean --install {below}?"
            if inner
            else "Give --install the install tree to check (its manifest may be kept anywhere).",
        )
    differences = compare(data["files"], file_hashes(tree, modes=data["format"] >= 2))
    for difference in differences:
        console.print(f"{difference.what:<8} {difference.path}")
    if differences:
        err_console.print(f"{tree} differs from {manifest} in {len(differences)} file(s)")
        raise typer.Exit(1)
    console.print(f"{tree} matches {manifest}: {len(data['files'])} file(s)")


@app.command()
@command
def new(
    name: Annotated[str, typer.Argument(help="Package name (lower case, digits, underscores).")],
    target: Annotated[
        str | None,
        typer.Option(help="The package's chip: written to its sdkconfig.defaults (CONFIG_IDF_TARGET)."),
    ] = None,
    depends: Annotated[
        list[str] | None, typer.Option("--depends", "-d", help="Interface package the firmware uses (repeatable).")
    ] = None,
    link: Annotated[
        str,
        typer.Option(
            "--transport",
            help="How the board reaches the micro-ROS agent: udp (Wi-Fi), serial or uart (UART0, the board's "
            "USB-to-UART bridge), usb-serial-jtag (the chip's own USB: esp32c3, esp32s3).",
        ),
    ] = "udp",
    workspace: WorkspaceOption = None,
) -> None:
    """Create NAME beside the workspace's firmware: an ESP-IDF project that is also a ROS 2 package,
    with a micro-ROS app on the shared espdock_uros component (added beside it if missing)."""
    ws, config = load(workspace)
    packages = workspace_packages(ws, config.ros_distro)
    check_new_package(name, tuple(depends or ()), packages)
    chip = target and check_target(target, "--target")
    chosen = transport.parse_transport(link)
    owner = invoking_user(os.environ, ws.root) if os.geteuid() == 0 else None
    path = create_firmware_package(ws, name, tuple(depends or ()), packages, owner, chip, chosen, config.target)
    console.print(f"created {path.relative_to(ws.root)}; build it with `espdock build {name}`")
    if chosen != transport.UDP:
        console.print(f"micro-ROS over {chosen}: no provisioning; start the agent with `espdock agent --port <device>`")
    where = f"CONFIG_IDF_TARGET in {name}/sdkconfig.defaults" if chip else "the workspace's `target`"
    console.print(f"chip target {chip or config.target} ({where})")


@app.command()
@command
def init(
    directory: Annotated[
        Path | None,
        typer.Argument(
            help="The workspace: empty, new, or an existing colcon workspace (default: the current directory; with "
            "--compose, the workspace it is in).",
            show_default=False,
        ),
    ] = None,
    compose: Annotated[
        bool,
        typer.Option(
            "--compose", help="Write compose.yaml again from the executables install/ holds now (after a build)."
        ),
    ] = False,
    force: Annotated[
        bool, typer.Option("--force", help="With --compose: replace an edited compose file (kept as <name>.orig).")
    ] = False,
) -> None:
    """Make DIRECTORY an espdock workspace: writes a commented espdock.toml with the layout it finds
    (and src/ if there is none) and a compose.yaml of its nodes. Only adds files, but
    `--compose` writes compose.yaml again, unless it was edited since."""
    if force and not compose:
        raise ConfigError("--force goes with --compose", "`espdock init --compose --force`.")
    if directory is None:
        directory = Path(".")
        if compose:  # from anywhere in the workspace, as the other commands run: its compose file
            with contextlib.suppress(WorkspaceError):
                directory = find_workspace().root
    # As root for someone else: the new files belong to who owns the nearest existing directory.
    # A clear error where the current directory is gone and DIRECTORY is relative to it.
    where = directory if directory.is_absolute() else current_dir() / directory
    existing = next(d for d in (where.resolve(), *where.resolve().parents) if d.exists())
    owner = invoking_user(os.environ, existing) if os.geteuid() == 0 else None
    ws, created = init_workspace(directory, owner)
    try:
        ws, config = load(ws.root)
        packages = workspace_packages(ws, config.ros_distro)
    except EspdockError:
        undo_init(ws.root, created)  # a package.xml to fix first: run again after, from where it was
        raise
    if "espdock.toml" not in created:
        console.print(f"{ws.root} is an espdock workspace already (espdock.toml exists)")
    else:
        console.print(f"made {ws.root} an espdock workspace: created {', '.join(created)}")
    unignored = unignored_outputs(ws.root, ws.colcon_root) if GITIGNORE not in created else []
    if unignored is None:
        notify(
            "note: git refuses to read this repository as this user (another user's: git's safe.directory), so "
            f"espdock could not check that its {GITIGNORE} leaves colcon's build/, install/ and log/ out"
        )
    elif unignored:
        # One a line: a colcon root with spaces in its name made one line look like two.
        shown = "".join(f"\n  {line}" for line in unignored)
        notify(
            f"note: git does not leave colcon's outputs out of this repository (the {GITIGNORE} here is yours, "
            f"kept as it is): add these lines to it:{shown}"
        )
    # espdock.toml's name, not ESPDOCK_NAME's (a worktree's own, for the while).
    by_setting = config.name is not None and not os.environ.get(NAME_VARIABLE)
    outcome = init_compose(
        ws, runtime_repository(config, ws), packages, owner, refresh=compose, force=force, by_setting=by_setting
    )
    if "espdock.toml" not in created and outcome in (None, "unchanged"):
        console.print("nothing changed")
    if outcome == "unchanged":
        console.print("compose.yaml is up to date with install/")
    elif outcome is not None:
        kept = " (yours is kept as its .orig)" if outcome == "replaced" else ""
        console.print(f"{outcome} compose.yaml: the built executables as services (`espdock compose up`){kept}")
    firmware = [p.name for p in packages if p.kind is PackageKind.FIRMWARE]
    ros = [p.name for p in packages if p.kind is PackageKind.ROS]
    console.print(f"layout: packages in {', '.join(ws.package_paths)}; colcon's build/install/log in {ws.colcon_root}")
    console.print(f"found {len(ros)} ROS package(s){': ' + ', '.join(ros) if ros else ''}")
    console.print(f"found {len(firmware)} firmware package(s){': ' + ', '.join(firmware) if firmware else ''}")
    for name, project in unmanifested(ws).items():  # an ESP-IDF project brought in, say: what makes it one
        notify(project.not_built(name))
    for line in search_warnings(ws):
        notify(line)
    top = ws.root / "CMakeLists.txt"
    if "espdock.toml" in created and top.is_file() and idf_project_cmake(top.read_text(errors="replace")):
        notify(
            f"note: {ws.root} is an ESP-IDF project itself, and packages are looked for in "
            f"{', '.join(ws.package_paths)}: to build it, give it a package.xml "
            '(<build_type>esp_idf</build_type>) and set package_paths = ["."] in espdock.toml'
        )
    if firmware and (skips := colcon_register.colcon_skips_firmware(dict(os.environ))):
        console.print(f"note: {skips}")
    # `cd -x` is an option to cd: a name that starts with a dash goes as ./-x.
    shown = str(directory) if directory.is_absolute() or not str(directory).startswith("-") else f"./{directory}"
    console.print("next:")
    if directory.resolve() != current_dir(Path("/")):
        # A line of its own: `cd DIR && ...` on each line, pasted in order, cd'd into DIR/DIR.
        console.print(f"  cd {shlex.quote(shown)}")
    if compose:  # after a build, to run what it built
        console.print("  espdock compose up        # the nodes compose.yaml names, each a service")
        return
    if not firmware:
        console.print("  espdock new my_board      # a firmware package (ESP-IDF project + ROS 2 package)")
    console.print("  espdock build             # images, then every package, each in its container")


@app.command()
@command
def setup() -> None:
    """Make this machine ready: a Docker engine (started or installed), Compose v2, the base image."""
    engine = bootstrap.ensure_engine(os.environ, notify)
    bootstrap.ensure_compose(os.environ, notify)
    try:
        ws, config = load(None)
    except WorkspaceError:
        console.print("engine and compose ready (not in a workspace: no base image to prepare)")
        return
    # The Dockerfile a build would use: the workspace's own, else espdock's default.
    inputs = read_build_inputs(ws, ())
    base = base_image(
        config, inputs.ros_official_dockerfile if config.ros_image == "official" else inputs.ros_dockerfile
    )
    if base:
        how = bootstrap.ensure_base_image(engine, base, config, notify)
        console.print(f"base image {base}: {how}")
    console.print("ready")


@app.command("list")
@command
def list_packages(
    workspace: WorkspaceOption = None,
    names: Annotated[
        bool, typer.Option("--names", "-n", help="Only the names, one per line (as `colcon list -n`), for scripts.")
    ] = False,
) -> None:
    """List the workspace's packages in build order."""
    ws, config = load(workspace)
    packages = workspace_packages(ws)
    if names:
        # A script's input: the names alone on stdout (a table's borders and title were all there
        # was to parse), what espdock warns of on stderr.
        console.print("\n".join(p.name for p in packages), markup=False, highlight=False, soft_wrap=True)
    else:
        firmware = tuple(p for p in packages if p.kind is PackageKind.FIRMWARE)
        render_packages(console, ws, packages, declared_chips(config, read_build_inputs(ws, firmware), firmware))
    said = [project.not_built(name) for name, project in unmanifested(ws).items()] + search_warnings(ws)
    for line in said:
        if names:
            err_console.print(line, markup=False, highlight=False, soft_wrap=True)
        else:
            notify(line)


colcon_extension = typer.Typer(
    help="espdock's colcon extension for a colcon that runs in another Python (apt's colcon, espdock from pipx).",
    no_args_is_help=True,
)
app.add_typer(colcon_extension, name="colcon-extension")
ColconOption = Annotated[
    str | None, typer.Option("--colcon", help="The colcon executable (default: `colcon` on PATH).")
]


@colcon_extension.command("install")
@command
def colcon_extension_install(colcon: ColconOption = None) -> None:
    """Register espdock's colcon extension with colcon's Python, so plain `colcon build` builds the
    firmware packages (colcon loads extensions only from its own Python)."""
    target = colcon_register.colcon_python(colcon, dict(os.environ))
    if target.found:
        console.print(f"colcon's Python {target.python} loads espdock's extension already ({target.found[0]})")
        return
    written = colcon_register.install_shim(target, colcon_register.espdock_site(), colcon_register.espdock_python())
    console.print(f"colcon ({target.python}) now loads espdock's extension: {', '.join(map(str, written))}")


@colcon_extension.command("check")
@command
def colcon_extension_check() -> None:
    """Fail when the `colcon` on PATH would skip firmware packages (it does not load espdock's extension)."""
    skips = colcon_register.colcon_skips_firmware(dict(os.environ))
    if skips is not None:
        raise ConfigError(skips)
    console.print("colcon on PATH builds firmware packages through espdock (or there is no colcon on PATH)")


@colcon_extension.command("uninstall")
@command
def colcon_extension_uninstall(colcon: ColconOption = None) -> None:
    """Remove what `espdock colcon-extension install` registered with colcon's Python."""
    target = colcon_register.colcon_python(colcon, dict(os.environ))
    removed = colcon_register.uninstall_shim(target.site_dir)
    console.print(f"removed {', '.join(map(str, removed))}" if removed else "nothing to remove")
