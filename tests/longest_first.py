"""Hand the longest test modules out first when pytest-xdist runs them (`make test`).

`--dist loadfile` gives each worker whole modules, and `--no-loadscope-reorder` keeps them in
collection order, which this plugin sets: the modules that took longest in the last run
first, so that no worker starts a minute of image builds while the others have nothing left.
xdist's own order (most tests first) put the integration modules with two or three long
tests last: one worker ran 72 s after another had finished.

The times come from pytest's cache (.pytest_cache), written at the end of every run for the
modules it ran. A module the cache does not know (a fresh clone, a new module) goes before
every known one, ordered by what its markers say: slow, then engine, then by test count."""

from __future__ import annotations

import pytest

CACHE_KEY = "espdock/module-seconds"


def _module(nodeid: str) -> str:
    return nodeid.split("::", 1)[0]


def order_key(module: str, items: list[pytest.Item], seconds: dict[str, float]) -> tuple:
    """Sort key of MODULE (its ITEMS): unknown modules first (by marker cost), then by SECONDS."""
    if module in seconds:
        return (1, -seconds[module])
    slow = any(item.get_closest_marker("slow") for item in items)
    engine = any(item.get_closest_marker("engine") for item in items)
    return (0, not slow, not engine, -len(items))


def pytest_collection_modifyitems(session: pytest.Session, config: pytest.Config, items: list[pytest.Item]) -> None:
    # Only an xdist worker's order decides who runs what; a run in one process keeps its order.
    if not hasattr(config, "workerinput"):
        return
    seconds = config.cache.get(CACHE_KEY, {}) if getattr(config, "cache", None) is not None else {}
    modules: dict[str, list[pytest.Item]] = {}
    for item in items:
        modules.setdefault(_module(item.nodeid), []).append(item)
    ordered = sorted(modules, key=lambda module: order_key(module, modules[module], seconds))
    items[:] = [item for module in ordered for item in modules[module]]


class ModuleTimes:
    """Sums each module's setup, call and teardown times as the reports arrive (on the controller
    under xdist), and merges them into the cache when the run ends."""

    def __init__(self, config: pytest.Config) -> None:
        self.config = config
        self.seconds: dict[str, float] = {}

    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        module = _module(report.nodeid)
        self.seconds[module] = self.seconds.get(module, 0.0) + report.duration

    def pytest_sessionfinish(self, session: pytest.Session, exitstatus: int) -> None:
        # A selection (-k, -m) or an interrupted run times part of a module: it would look short.
        option = self.config.option
        if self.seconds and not option.keyword and not option.markexpr and exitstatus != pytest.ExitCode.INTERRUPTED:
            known = self.config.cache.get(CACHE_KEY, {})
            known.update({module: round(seconds, 1) for module, seconds in self.seconds.items()})
            self.config.cache.set(CACHE_KEY, known)


def pytest_configure(config: pytest.Config) -> None:
    # Workers send their reports to the controller, which sees them all: it alone records.
    if not hasattr(config, "workerinput") and getattr(config, "cache", None) is not None:
        config.pluginmanager.register(ModuleTimes(config), "espdock-module-times")
