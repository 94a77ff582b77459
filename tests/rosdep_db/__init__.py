"""A rosdep database for the tests: real rules from rosdistro (base.yaml, python.yaml and a cut
of jazzy's distribution file) for the keys the tests use, read through rosdep's own
sources.list.d and ROSDISTRO_INDEX_URL mechanisms, since GitHub is unreachable here.

    env = environment(tmp_path)   # ROSDEP_SOURCE_PATH, ROSDISTRO_INDEX_URL, XDG_CACHE_HOME
"""

from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent


def environment(tmp: Path) -> dict[str, str]:
    """The variables that point rosdep (and espdock's cache of its database) at this directory;
    the sources list is written under TMP, since a file:// URL must be absolute."""
    sources = tmp / "rosdep-sources.list.d"
    sources.mkdir(parents=True, exist_ok=True)
    (sources / "50-espdock-tests.list").write_text(
        f"yaml {(HERE / 'base.yaml').as_uri()}\nyaml {(HERE / 'python.yaml').as_uri()}\n"
    )
    return {
        "ROSDEP_SOURCE_PATH": str(sources),
        "ROSDISTRO_INDEX_URL": (HERE / "rosdistro" / "index-v4.yaml").as_uri(),
        "XDG_CACHE_HOME": str(tmp / "cache"),
        # A developer's build, which writes a missing rosdep lock (under CI=true `build` refuses
        # one instead, as the tests of --locked show).
        "CI": "",
    }
