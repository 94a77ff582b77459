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


# What a pinned clone honours; every other option is refused, not guessed at: an option that
# takes a value (--template, -j, --reference-if-able, --shallow-since ...) read as a flag would
# make its value the URL, and --recursive or --no-checkout asked for something a one-commit
# checkout does not give.
CLONE_VALUE_OPTIONS = ("-b", "--branch", "--depth")
CLONE_FLAGS = ("-q", "--quiet", "--single-branch", "--no-single-branch", "--no-tags", "--progress", "-v", "--verbose")


class Refused(Exception):
    """A git command line the pinned git cannot honour."""


def parse_clone(args: list[str]) -> tuple[str | None, str, str]:
    """(branch, url, destination) of `git clone [-b BRANCH] [--depth N] [-q] URL [DEST]`."""
    branch, positional, i = None, [], 0
    while i < len(args):
        arg = args[i]
        if arg == "--":
            positional += args[i + 1 :]
            break
        if arg in CLONE_VALUE_OPTIONS:
            if i + 1 >= len(args):
                raise Refused(f"`git clone {arg}` without its value")
            if arg in ("-b", "--branch"):
                branch = args[i + 1]
            i += 2
            continue
        if arg.startswith(("--branch=", "--depth=")):
            if arg.startswith("--branch="):
                branch = arg.split("=", 1)[1]
        elif arg in CLONE_FLAGS:
            pass
        elif arg.startswith("-"):
            raise Refused(
                f"`git clone {arg}`: the pinned checkout gives one commit, without submodules, tags or other "
                "checkout modes, so it honours only -b/--branch, --depth, -q and --[no-]single-branch"
            )
        else:
            positional.append(arg)
        i += 1
    if not positional or len(positional) > 2:
        raise Refused(f"`git clone {' '.join(args)}`: expected a repository and at most a directory")
    url = positional[0]
    dest = positional[1] if len(positional) > 1 else normalise(url).rsplit("/", 1)[-1]
    return branch, url, dest


def split_global(argv: list[str]) -> tuple[str | None, list[str]]:
    """(directory of -C, or None; the command and its arguments) of `git [-C DIR] COMMAND ...`.

    -C is honoured for a clone (the destination is relative to it); `-c`, `--git-dir` and every
    other global option would change what a clone does and are refused for one."""
    directory, i = None, 0
    while i < len(argv) and argv[i].startswith("-"):
        if argv[i] == "-C" and i + 1 < len(argv):
            directory = os.path.join(directory or "", argv[i + 1])
            i += 2
            continue
        if "clone" in argv[i:]:
            raise Refused(f"`git {argv[i]} ... clone`: a global option the pinned clone cannot honour")
        return None, argv  # not a clone: the real git gets it as it is
    return directory, argv[i:]


def fail(message: str) -> int:
    print(f"pinned git: error: {message}", file=sys.stderr, flush=True)
    with FAILED_MARKER.open("a") as marker:
        marker.write(message + "\n")
    return 1


def main(argv: list[str]) -> int:
    git = os.environ["ESPDOCK_REAL_GIT"]
    try:
        directory, command = split_global(argv)
        if not command or command[0] != "clone":
            os.execv(git, [git, *argv])
        branch, url, dest = parse_clone(command[1:])
    except Refused as refused:
        return fail(f"{refused} (git {' '.join(argv)})")
    if directory is not None:
        dest = os.path.join(directory, dest)
    sources = Path(os.environ["ESPDOCK_MICRO_ROS_SOURCES"])
    pin = read_pins(sources).get(normalise(url))
    if pin is None:
        return fail(
            f"{url} is cloned by the micro-ROS build but not pinned in {sources.name}; add `{url} BRANCH COMMIT`"
        )
    pinned_branch, commit = pin
    if branch is not None and branch != pinned_branch:
        return fail(
            f"{url} is cloned at branch {branch}, but {sources.name} pins it on {pinned_branch}; update the pin"
        )
    if commit == FOLLOW_HEAD:
        fetch = [git, "-C", dest, "fetch", "-q", "--depth", "1", "origin", f"refs/heads/{pinned_branch}"]
    else:
        fetch = [git, "-C", dest, "fetch", "-q", "--depth", "1", "origin", commit]
    # origin is the URL, as after a clone; the branch points at the checkout. No tags: a later
    # `git checkout TAG` fails, naming the tag.
    steps = (
        [git, "init", "-q", dest],
        [git, "-C", dest, "remote", "add", "origin", url],
        fetch,
        [git, "-C", dest, "checkout", "-q", "-B", pinned_branch, "FETCH_HEAD"],
    )
    for step in steps:
        if subprocess.run(step, check=False).returncode != 0:
            return fail(f"could not fetch {url} at {commit} (branch {pinned_branch})")
    got = subprocess.run([git, "-C", dest, "rev-parse", "HEAD"], capture_output=True, text=True, check=True)
    got_commit = got.stdout.strip()
    if commit == FOLLOW_HEAD:
        print(
            f"pinned git: warning: {url} is not pinned; took {got_commit} from the head of {pinned_branch}",
            file=sys.stderr,
            flush=True,
        )
    else:
        print(f"pinned git: {url} at {commit[:12]} ({pinned_branch})", flush=True)
    resolved = os.environ.get("ESPDOCK_MICRO_ROS_RESOLVED")
    if resolved:
        with open(resolved, "a") as out:
            out.write(f"{url} {pinned_branch} {got_commit}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
