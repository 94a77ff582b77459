"""`git` for the micro-ROS library build: every clone at the commit micro_ros_sources.txt pins.

micro_ros_espidf_component's libmicroros.mk clones some 25 repositories at the head of a
branch (`git clone -b jazzy URL DEST`), so the library would depend on the day it was built
while its image key says otherwise. In the image build, a `git` that runs this stands first
on PATH: a clone of a listed repository fetches exactly the listed commit; a clone of an
unlisted repository, or of another branch than the one listed (upstream moved on), fails and
names it, and leaves a marker the Dockerfile checks, since libmicroros.mk ignores the exit
status of its clones. A repository listed with commit "-" follows its branch head, with a
warning. Every clone's commit is appended to ESPDOCK_MICRO_ROS_RESOLVED, which the image
keeps, so `espdock micro-ros pin` can write the heads it got into the pins. Every other git
command goes to the real git.

    ESPDOCK_REAL_GIT=/usr/bin/git ESPDOCK_MICRO_ROS_SOURCES=micro_ros_sources.txt \
        python3 pinned_git.py clone -b jazzy https://github.com/ros2/rcl src/rcl
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

FAILED_MARKER = Path(os.environ.get("ESPDOCK_PIN_FAILURES", "/tmp/espdock-unpinned-clones"))
FOLLOW_HEAD = "-"


def normalise(url: str) -> str:
    return url.rstrip("/").removesuffix(".git").lower()


def read_pins(path: Path) -> dict[str, tuple[str, str]]:
    """{normalised url: (branch, commit)} from lines `URL BRANCH COMMIT`; # starts a comment."""
    pins = {}
    for number, line in enumerate(path.read_text().splitlines(), 1):
        fields = line.split("#", 1)[0].split()
        if not fields:
            continue
        if len(fields) != 3 or not (len(fields[2]) == 40 or fields[2] == FOLLOW_HEAD):
            sys.exit(f"{path}:{number}: expected `URL BRANCH COMMIT` with a 40-hex commit or -, got {line!r}")
        pins[normalise(fields[0])] = (fields[1], fields[2])
    return pins


def parse_clone(args: list[str]) -> tuple[str | None, str, str]:
    """(branch, url, destination) of `git clone [-b BRANCH] [options] URL [DEST]`."""
    branch, positional, i = None, [], 0
    while i < len(args):
        arg = args[i]
        if arg in ("-b", "--branch"):
            branch, i = args[i + 1], i + 2
            continue
        if arg.startswith("--branch="):
            branch = arg.split("=", 1)[1]
        elif arg in ("--depth", "-o", "--origin", "-c", "--config", "--reference"):
            i += 1
        elif not arg.startswith("-"):
            positional.append(arg)
        i += 1
    if not positional:
        sys.exit("pinned git: clone without a repository")
    url = positional[0]
    dest = positional[1] if len(positional) > 1 else normalise(url).rsplit("/", 1)[-1]
    return branch, url, dest


def fail(message: str) -> int:
    print(f"pinned git: error: {message}", file=sys.stderr, flush=True)
    with FAILED_MARKER.open("a") as marker:
        marker.write(message + "\n")
    return 1


def main(argv: list[str]) -> int:
    git = os.environ["ESPDOCK_REAL_GIT"]
    if not argv or argv[0] != "clone":
        os.execv(git, [git, *argv])
    sources = Path(os.environ["ESPDOCK_MICRO_ROS_SOURCES"])
    branch, url, dest = parse_clone(argv[1:])
    pin = read_pins(sources).get(normalise(url))
    if pin is None:
        return fail(f"{url} is cloned by the micro-ROS build but not pinned in {sources.name}; add `{url} BRANCH COMMIT`")
    pinned_branch, commit = pin
    if branch is not None and branch != pinned_branch:
        return fail(f"{url} is cloned at branch {branch}, but {sources.name} pins it on {pinned_branch}; update the pin")
    if commit == FOLLOW_HEAD:
        fetch = [git, "-C", dest, "fetch", "-q", "--depth", "1", url, f"refs/heads/{pinned_branch}"]
    else:
        fetch = [git, "-C", dest, "fetch", "-q", "--depth", "1", url, commit]
    for command in ([git, "init", "-q", dest], fetch, [git, "-C", dest, "checkout", "-q", "FETCH_HEAD"]):
        if subprocess.run(command, check=False).returncode != 0:
            return fail(f"could not fetch {url} at {commit} (branch {pinned_branch})")
    got = subprocess.run([git, "-C", dest, "rev-parse", "HEAD"], capture_output=True, text=True, check=True)
    got_commit = got.stdout.strip()
    if commit == FOLLOW_HEAD:
        print(f"pinned git: warning: {url} is not pinned; took {got_commit} from the head of {pinned_branch}",
              file=sys.stderr, flush=True)
    else:
        print(f"pinned git: {url} at {commit[:12]} ({pinned_branch})", flush=True)
    resolved = os.environ.get("ESPDOCK_MICRO_ROS_RESOLVED")
    if resolved:
        with open(resolved, "a") as out:
            out.write(f"{url} {pinned_branch} {got_commit}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
