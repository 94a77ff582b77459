"""What espdock writes under a home that is not root's while it runs as root with it (`sudo -E
espdock ...`, `sudo --preserve-env=HOME`), and in that user's cache and state dirs outside it:
handed to the home's owner when the command ends. Left root's, a new ~/.cache kept the user's
pip out of it, and their next espdock could not record its images ("Permission denied")."""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from pathlib import Path

from espdock.errors import EspdockError
from espdock.layout import xdg_dir


def kept(env: Mapping[str, str]) -> Callable[[], None]:
    """What hands espdock's directories under ENV's home (its cache, its state, rosdep's and uv's
    caches, and the missing directories above them it makes) to the home's owner: to call as the
    command ends. A root ~/.ros/rosdep made the user's next `espdock lock` fail on rosdep's cache."""
    if os.geteuid() != 0 or not env.get("HOME"):
        return lambda: None
    from espdock.images.contexts import config_dir  # here: every command starts through this module
    from espdock.images.prune import state_dir

    home = Path(env["HOME"])
    try:
        info = home.stat()
        cache = xdg_dir(env, "XDG_CACHE_HOME", ".cache")
        # espdock's cache and state; rosdep's meta cache (in ROS_HOME) and uv's, which it runs; and
        # the docker CLI's, where Compose's image builds write buildx's state (a root
        # ~/.docker/buildx/current failed the user's next image build: "permission denied").
        ros_home = Path(env.get("ROS_HOME") or home / ".ros")
        uv_cache = Path(env.get("UV_CACHE_DIR") or cache / "uv")
        ours = [cache / "espdock", state_dir(env), ros_home / "rosdep", uv_cache, config_dir(env)]
        # Where they are, not how they are written: `$HOME/../x` and a ~/.cache linked to a
        # directory of root's were taken as the home's, and what root made in them handed over.
        home, ours = home.resolve(), [path.resolve() for path in ours]
    except (OSError, EspdockError, RuntimeError):
        return lambda: None
    if info.st_uid == 0:
        return lambda: None
    owner = (info.st_uid, info.st_gid)
    # Each directory with the one above it that is the user's: the home, or, for one outside it
    # (XDG_STATE_HOME=/scratch/me/state, a home quota's habit), the nearest that is there and theirs.
    tops = {path: home if path.is_relative_to(home) else _nearest(path) for path in ours if path != home}
    tops = {path: top for path, top in tops.items() if top == home or (top is not None and _owned_by(top, owner[0]))}
    ours = list(tops)
    made = sorted(
        {
            p
            for path, top in tops.items()
            for p in (path, *path.parents)
            if p.is_relative_to(top) and p != top and not p.exists()
        },
        key=lambda p: len(p.parts),
    )

    def hand_back() -> None:
        for path in made:  # ~/.cache, ~/.local, ~/.local/state, as they were made: parents first
            if path.is_dir() and not path.is_symlink() and path.stat().st_uid == 0:
                os.chown(path, *owner)
        for path in ours:
            try:
                # Only a tree the home's owner has (or this run made, handed over above): where a
                # link leads ~/.cache/espdock to one of root's (/etc), its files stay root's.
                if os.stat(path).st_uid != owner[0]:
                    continue
            except OSError:
                continue
            for directory, dirnames, filenames in os.walk(path):
                for name in (".", *dirnames, *filenames):
                    entry = os.path.join(directory, name)
                    if os.lstat(entry).st_uid == 0:
                        os.chown(entry, *owner, follow_symlinks=False)

    return hand_back


def _nearest(path: Path) -> Path | None:
    """PATH or the nearest directory above it that is there (None: only the root is)."""
    for candidate in (path, *path.parents):
        if candidate.exists():
            return candidate if candidate != Path(candidate.anchor) else None
    return None


def _owned_by(path: Path, uid: int) -> bool:
    try:
        return path.stat().st_uid == uid
    except OSError:
        return False
