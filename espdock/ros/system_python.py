"""The official ROS image's system Python: its version and every distribution installed in it
(by apt: Ubuntu's python3-* packages and the ros-<distro>-* packages' own), read by running
the image once. The rosdep lock's pip part for that image is resolved under these pins, as
rosdep's own pip installs leave what is installed alone: pip then adds packages beside apt's
instead of replacing them (noble's numpy 1.26, which its cv_bridge and scipy were built
against, stays numpy 1.26)."""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from espdock.errors import LockError

MARK = "ESPDOCK-SYSTEM-PYTHON "
# Run by the image's own Python through its entrypoint (which sources ROS's setup: ROS's
# Python packages on PYTHONPATH, as the nodes see them).
PROBE = (
    "import importlib.metadata as m, json, sys; "
    "found = sorted({(d.metadata['Name'], d.version) for d in m.distributions() if d.metadata['Name']}); "
    f"print({MARK!r} + json.dumps({{'version': '%d.%d' % sys.version_info[:2], 'installed': found}}))"
)
# A version pip and uv can compare (PEP 440, local part allowed); Debian's odd ones are left out.
_PEP440 = re.compile(r"^\d+(\.\d+)*((a|b|rc)\d+)?(\.post\d+)?(\.dev\d+)?(\+[a-z0-9]+([._-][a-z0-9]+)*)?$", re.I)


@dataclass(frozen=True)
class SystemPython:
    version: str  # "3.12"
    installed: tuple[tuple[str, str], ...] = ()  # (distribution, version)

    def constraints(self) -> str:
        """uv/pip constraints that keep every installed distribution at its version."""
        return "".join(f"{name}=={version}\n" for name, version in self.installed if _PEP440.match(version))

    def pins(self) -> Mapping[str, str]:
        """Installed versions by normalised distribution name."""
        return {normalise(name): version for name, version in self.installed}


def normalise(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def parse_probe(lines: list[str]) -> SystemPython:
    """What PROBE printed; a LockError when it printed nothing usable."""
    for line in lines:
        if line.startswith(MARK):
            data = json.loads(line.removeprefix(MARK))
            return SystemPython(str(data["version"]), tuple((str(n), str(v)) for n, v in data["installed"]))
    raise LockError(
        "could not read the official ROS image's Python (its version and installed packages): "
        + (" ".join(lines)[-300:] or "no output"),
        "Check that the image runs `python3` (ESPDOCK_BASE_IMAGE / base_image), then run `espdock lock`.",
    )


def probe_image(ref: str, run: Callable[[tuple[str, ...]], tuple[int, list[str]]]) -> SystemPython:
    """The system Python of image REF, RUN (argv -> exit code, output lines) running it."""
    code, lines = run(("python3", "-c", PROBE))
    if code != 0:
        raise LockError(
            f"running python3 in {ref} failed (exit code {code}): {' '.join(lines)[-300:]}",
            "Check the image (ESPDOCK_BASE_IMAGE / base_image), then run `espdock lock`.",
        )
    return parse_probe(lines)
