"""Keeping the engine's disk bounded: which keyed images each workspace used, and which may go.

Every build (and every `run` or `compose` that makes the runtime image) records, per workspace,
the keyed images it used (tag, kind, when) in espdock's state directory ($ESPDOCK_STATE_DIR, else
$XDG_STATE_HOME/espdock, else ~/.local/state/espdock), one file per workspace root. `espdock prune`
removes a workspace's images its current inputs no longer use, keeping the last few generations of
each kind; an image another recorded workspace's last build used, or a running container's, stays.
Images no record names (another user's, a test's, a pulled base) are never candidates.
"""

from __future__ import annotations

import dataclasses
import fcntl
import json
import os
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from espdock import durable
from espdock.build.steps import LABEL_KEY
from espdock.errors import ConfigError
from espdock.images.engine import Engine
from espdock.layout import xdg_dir
from espdock.workspace import root_key, workspace_gone

GB = 1000**3


def state_dir(env: Mapping[str, str]) -> Path:
    """Where espdock keeps what outlives a workspace's build tree (the image records)."""
    if value := env.get("ESPDOCK_STATE_DIR"):
        if not os.path.isabs(value):
            # Relative to wherever espdock runs: a build from src/ made one there, in the sources.
            raise ConfigError(
                f"ESPDOCK_STATE_DIR must be an absolute path, got {value!r}",
                "espdock runs from any directory of a workspace: give the whole path "
                f'(`"{"$HOME" + value[1:] if value == "~" or value.startswith("~/") else "$PWD/" + value}"`).',
            )
        return Path(value)
    return xdg_dir(env, "XDG_STATE_HOME", ".local/state") / "espdock"


@dataclass(frozen=True)
class UsedImage:
    tag: str
    repository: str
    used: float  # when a build last used it (seconds since the epoch)


@dataclass(frozen=True)
class Record:
    """What one workspace's builds used: every keyed image (latest use), and its last build's set."""

    root: str
    images: tuple[UsedImage, ...]
    current: frozenset[str]


def _record_path(state: Path, root: Path | str) -> Path:
    return state / "workspaces" / f"{root_key(root)}.json"


def has_record(state: Path, root: Path | str) -> bool:
    """Whether a build of the workspace at ROOT recorded the images it used in STATE."""
    return _record_path(state, root).is_file()


@contextmanager
def _changing(path: Path) -> Iterator[None]:
    """Hold the record at PATH for one read, change and write: two commands of a workspace at once
    (two `espdock run`s, a build and a `compose up`) each wrote back what they had read, and the
    last one dropped the other's images, which another workspace's prune could then remove."""
    path.parent.mkdir(parents=True, mode=0o700, exist_ok=True)
    fd = os.open(path.with_suffix(".lock"), os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def _read_record(path: Path) -> Record | None:
    """The record in PATH, None when it is missing or unreadable (a record only protects or offers images)."""
    try:
        data = json.loads(path.read_text())
        images = tuple(
            UsedImage(tag, str(item["repository"]), float(item["used"])) for tag, item in data["images"].items()
        )
        return Record(str(data["root"]), images, frozenset(data.get("current", ())))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None


def read_records(state: Path) -> list[Record]:
    """Every workspace's record (unreadable files skipped)."""
    records = (_read_record(path) for path in sorted((state / "workspaces").glob("*.json")))
    return [record for record in records if record is not None]


def gone_workspaces(records: Iterable[Record]) -> set[str]:
    """The roots of RECORDS whose workspace directory no longer exists (a clone removed, a CI
    job's checkout): no build will use their images again."""
    return {record.root for record in records if workspace_gone(record.root)}


def record_use(state: Path, root: Path, used: Iterable[tuple[str, str]], now: float, whole: bool = True) -> None:
    """Record that ROOT's build used USED (tag, repository) at NOW: those become its current image of
    each kind; kinds the build did not touch (a --only build) keep their current one. Not WHOLE (a
    build of some packages): the kinds it touched keep theirs too, as one kind may hold more than
    one current image (a micro-ROS image per library inputs): the build of one firmware package
    dropped the others' images, and another workspace's prune removed them."""
    used = dict(used)
    if not used:
        return
    path = _record_path(state, root)
    with _changing(path):
        _record_use(path, root, used, now, whole)


def _record_use(path: Path, root: Path, used: dict[str, str], now: float, whole: bool) -> None:
    # Only this workspace's own file: every build reading every workspace's record cost a build
    # 45 ms on a machine that had recorded 133 (125 of them since removed).
    previous = _read_record(path)
    if previous is not None and previous.root != str(root):
        previous = None
    images = {i.tag: {"repository": i.repository, "used": i.used} for i in (previous.images if previous else ())}
    for tag, repository in used.items():
        images[tag] = {"repository": repository, "used": now}
    kinds = set(used.values())
    kept = {
        t
        for t in (previous.current if previous else ())
        if not whole or images.get(t, {}).get("repository") not in kinds
    }
    data = {"root": str(root), "images": images, "current": sorted(kept | set(used))}
    durable.write_text(path, json.dumps(data, indent=1, sort_keys=True) + "\n")


def forget_images(state: Path, root: str, tags: Iterable[str]) -> None:
    """Drop TAGS (removed from the engine) from ROOT's record."""
    path = _record_path(state, root)
    if not path.is_file():
        return
    with _changing(path):
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError):
            return
        for tag in tags:
            data.get("images", {}).pop(tag, None)
        durable.write_text(path, json.dumps(data, indent=1, sort_keys=True) + "\n")


def forget_workspace(state: Path, root: str) -> None:
    """Drop ROOT's record: its workspace is gone and none of its images is left."""
    path = _record_path(state, root)
    path.unlink(missing_ok=True)
    path.with_suffix(".lock").unlink(missing_ok=True)


@dataclass(frozen=True)
class Present:
    """A keyed image on the engine, by one of its tags."""

    tag: str
    image_id: str
    size: int  # bytes no other image shares (what removing it frees when its last tag goes)


@dataclass(frozen=True)
class Decision:
    tag: str
    workspace: str
    size: int
    reason: str  # why it goes, or why it stays


@dataclass(frozen=True)
class PrunePlan:
    remove: tuple[Decision, ...]
    keep: tuple[Decision, ...]
    # Removed workspaces, not among the targets, whose images are still on the engine.
    gone_elsewhere: tuple[str, ...] = ()

    @property
    def freed(self) -> int:
        """Bytes the removals free (an image two removed tags name counted once)."""
        return sum(d.size for d in self.remove)


def plan_prune(
    records: Iterable[Record],
    targets: Iterable[str],
    current: Mapping[str, Iterable[str]],
    present: Iterable[Present],
    users: Mapping[str, tuple[bool, str]],
    keep: int,
    gone: Iterable[str] = (),
) -> PrunePlan:
    """Which of TARGETS' (workspace roots) recorded images to remove.

    Each target keeps what CURRENT (root -> tags its inputs use now; else what its last build
    used) names and, of each kind (repository), the KEEP most recently used others. An image
    stays, too, when another record's last build used it, when a container, running or stopped,
    uses it (USERS: image id -> whether one runs, and its name; the engine refuses to remove such
    an image, and the dry run listed it), or when it is no longer on the engine (PRESENT). A GONE workspace (its
    root removed) keeps nothing and protects nothing: no build will use its images again."""
    records = list(records)
    targets = set(targets)
    gone = set(gone)
    on_engine = {p.tag: p for p in present}
    remove: list[Decision] = []
    kept: list[Decision] = []
    for record in records:
        if record.root not in targets:
            continue
        removed = record.root in gone
        # What a workspace's inputs use now, where CURRENT says: its record's "current" keeps a
        # kind no package uses any more (a chip whose last package went, a one-off --target).
        # Other workspaces' are what their last builds used.
        if removed:
            now_used = set()
        elif record.root in current:
            now_used = set(current[record.root])
        else:
            now_used = set(record.current)
        others = {tag for other in records if other.root not in (record.root, *gone) for tag in other.current}
        by_kind: dict[str, list[UsedImage]] = {}
        for image in record.images:
            by_kind.setdefault(image.repository, []).append(image)
        for images in by_kind.values():
            older = sorted((i for i in images if i.tag not in now_used), key=lambda i: i.used, reverse=True)
            for index, image in enumerate(older):
                there = on_engine.get(image.tag)
                if there is None:
                    continue
                decision = _decide(image, there, index, 0 if removed else keep, others, users)
                if decision is None:
                    reason = "its workspace is gone" if removed else "no longer used by its inputs"
                    remove.append(Decision(image.tag, record.root, there.size, reason))  # sized once below
                else:
                    kept.append(Decision(image.tag, record.root, there.size, decision))
        for tag in sorted(now_used):
            if tag in on_engine:
                kept.append(Decision(tag, record.root, on_engine[tag].size, "used by the current inputs"))
    # A tag two targets recorded: kept by either keeps it.
    kept_tags = {d.tag for d in kept}
    # Gone workspaces with images of their own left (one a live workspace lists too is its to prune).
    live = _live_tags(records, gone)
    elsewhere = tuple(
        sorted(
            r.root
            for r in records
            if r.root in gone - targets and any(i.tag in on_engine and i.tag not in live for i in r.images)
        )
    )
    # A tag two targets recorded is removed once, by the first decision.
    once: dict[str, Decision] = {}
    for decision in remove:
        if decision.tag not in kept_tags:
            once.setdefault(decision.tag, decision)
    # The `:latest` of a name nothing of which stays, and no live workspace's last build used (a
    # removed workspace's, a former name's): no build makes it again, and it kept its image, unsaid.
    named_now = {tag.rpartition(":")[0] for r in records if r.root not in gone for tag in r.current}
    staying = {tag.rpartition(":")[0] for tag in on_engine if tag not in once and not tag.endswith(":latest")}
    for tag, decision in list(once.items()):
        repository = tag.rpartition(":")[0]
        latest = f"{repository}:latest"
        if latest in on_engine and latest not in once and latest not in kept_tags:
            if repository not in named_now and repository not in staying:
                once[latest] = Decision(latest, decision.workspace, 0, f"no image of {repository} stays")
    # What each removal frees: an image's bytes once, and none where it keeps a tag no decision
    # removes ("removed espdock/old:k1 (475 kB)", and the image stayed under another tag).
    tags_of: dict[str, set[str]] = {}
    for there in on_engine.values():
        tags_of.setdefault(there.image_id, set()).add(there.tag)
    counted: set[str] = set()
    for tag, decision in once.items():
        image_id = on_engine[tag].image_id
        if left := sorted(tags_of.get(image_id, set()) - set(once)):
            size, reason = 0, f"{decision.reason}; its image stays, tagged {', '.join(left)}"
        else:
            size, reason = (0 if image_id in counted else on_engine[tag].size), decision.reason
            counted.add(image_id)
        once[tag] = dataclasses.replace(decision, size=size, reason=reason)
    # And kept once, for its strongest reason: records are read in the order of their file names
    # (hashes of the roots), so "the first reason" would differ from machine to machine.
    kept_once: dict[str, Decision] = {}
    for decision in kept:
        held = kept_once.get(decision.tag)
        if held is None or _strength(decision.reason) < _strength(held.reason):
            kept_once[decision.tag] = decision
    return PrunePlan(tuple(once.values()), tuple(kept_once.values()), elsewhere)


_STRONGEST_FIRST = (
    "used by the current inputs",
    "a running container uses it",
    "another workspace's last build used it",
)


def _strength(reason: str) -> int:
    """REASON's rank among the reasons an image is kept (0: the strongest); "one of the last N"
    ranks last, as only a --keep protects it."""
    if reason.startswith(STOPPED):
        return _STRONGEST_FIRST.index("a running container uses it")
    return _STRONGEST_FIRST.index(reason) if reason in _STRONGEST_FIRST else len(_STRONGEST_FIRST)


STOPPED = "a stopped container uses it"


def _decide(
    image: UsedImage, there: Present, index: int, keep: int, others: set[str], users: Mapping[str, tuple[bool, str]]
) -> str | None:
    if index < keep:
        return f"one of the last {keep} of its kind"
    if image.tag in others:
        return "another workspace's last build used it"
    if there.image_id in users:
        running, name = users[there.image_id]
        return "a running container uses it" if running else f"{STOPPED} ({name}; `docker rm {name}` lets it go)"
    return None


def size_text(size: int) -> str:
    """SIZE in bytes as docker prints it (1000-based)."""
    value = float(size)
    for unit in ("B", "kB", "MB", "GB"):
        if value < 1000 or unit == "GB":
            return f"{value:.0f} {unit}" if unit == "B" else f"{value:.2f} {unit}"
        value /= 1000
    return f"{value:.2f} TB"


def present_images(listing: Iterable[tuple[str, tuple[str, ...], int, int]]) -> list[Present]:
    """Each tag of the engine's keyed images (Engine.labelled_images) as a Present."""
    return [Present(tag, image_id, unique) for image_id, tags, unique, _ in listing for tag in tags]


def images_total(listing: Iterable[tuple[str, tuple[str, ...], int, int]]) -> int:
    """What the keyed images take at most: each image's size, shared layers counted with each."""
    return sum(size for _, _, _, size in listing)


def prune_images(
    engine: Engine, state: Path, root: str, current: set[str], keep: int, all_workspaces: bool, dry_run: bool
) -> tuple[PrunePlan, list[str]]:
    """Plan (and unless DRY_RUN, carry out) the removal for the workspace at ROOT, whose inputs use
    the CURRENT tags now (or for every workspace recorded in STATE); return the plan and the tags
    a stopped container kept."""
    records = read_records(state)
    targets = {r.root for r in records} if all_workspaces else {root}
    current_tags = {root: current}
    listing = engine.labelled_images(LABEL_KEY, shared=True)
    present = present_images(listing)
    gone = gone_workspaces(records)
    plan = plan_prune(records, targets, current_tags, present, engine.image_users(), keep, gone)
    busy: list[str] = []
    if not dry_run:
        removed: dict[str, list[str]] = {}
        for decision in plan.remove:
            if engine.remove_tag(decision.tag):
                removed.setdefault(decision.workspace, []).append(decision.tag)
            else:
                busy.append(decision.tag)
        for workspace, tags in removed.items():
            forget_images(state, workspace, tags)
        left = {p.tag for p in present} - {tag for tags in removed.values() for tag in tags}
        for gone_root in forgettable(records, gone & targets, left):
            forget_workspace(state, gone_root)
    return plan, busy


def forgettable(records: Iterable[Record], gone: Iterable[str], left: Iterable[str]) -> list[str]:
    """The GONE workspaces whose records can go: none of the images they list is LEFT on the engine
    but for those a live workspace's record lists too, which that one's prune decides. Kept for
    such an image (another workspace's last build used it), the record stayed, and every prune
    after said to run `--all-workspaces` for it, which removed nothing."""
    records = list(records)
    gone = set(gone)
    left = set(left) - _live_tags(records, gone)
    return [r.root for r in records if r.root in gone and not any(i.tag in left for i in r.images)]


def _live_tags(records: Iterable[Record], gone: set[str]) -> set[str]:
    """The tags the records of workspaces not GONE list."""
    return {image.tag for record in records if record.root not in gone for image in record.images}


def trim_cache(engine: Engine, bound_gb: float, dry_run: bool) -> tuple[int | None, int]:
    """BuildKit's cache size (None: unknown just now), and what trimming it to BOUND_GB freed
    (0 on a dry run)."""
    size = engine.build_cache_size()
    if dry_run or (size is not None and size <= bound_gb * GB):
        return size, 0
    return size, engine.trim_build_cache(int(bound_gb * GB))
