"""Packaging hook: the wheel carries the repository's workspace files as espdock's defaults.

espdock builds in any workspace: where a workspace has no Dockerfile.ros, Dockerfile.idf,
docker/ or espdock_uros component of its own, it uses these (espdock/defaults.py). They are
copied from the repository root at build time, so the repository keeps one source of each.
"""

import shutil
import sys
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))
from espdock.defaults import PACKAGED, SHIPPED  # noqa: E402  (stdlib-only module of the source tree)

# Caches and editors' leftovers beside the defaults: never shipped.
LEFTOVERS = shutil.ignore_patterns("__pycache__", "*~", ".#*", "*.swp", "*.orig", "*.rej")


class BuildWithWorkspaceDefaults(build_py):
    def run(self) -> None:
        # build/lib outlives a build in the checkout: a module, template or default deleted since
        # must not ship again.
        shutil.rmtree(Path(self.build_lib) / "espdock", ignore_errors=True)
        super().run()
        target = Path(self.build_lib) / "espdock" / PACKAGED
        for rel in SHIPPED:
            source, dest = ROOT / rel, target / rel
            dest.parent.mkdir(parents=True, exist_ok=True)
            if source.is_dir():
                shutil.copytree(source, dest, dirs_exist_ok=True, ignore=LEFTOVERS)
            else:
                shutil.copy2(source, dest)


setup(cmdclass={"build_py": BuildWithWorkspaceDefaults})
