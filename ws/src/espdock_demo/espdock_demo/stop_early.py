"""Imported first by every node module, before anything slow to import: a SIGTERM or SIGINT that
comes while the node is still starting (its imports take a second or more on a busy machine)
ends it with exit 0 and no traceback, as a stop. spin_node takes the signals over from there."""

from __future__ import annotations

import os
import signal


def _stop(_signum: int, _frame: object) -> None:
    # Nothing is open yet, so nothing to clean up. Not SystemExit: raised where the handler happens
    # to run (a weakref callback of the import machinery, a __del__) Python prints and drops it.
    os._exit(0)


for _signum in (signal.SIGTERM, signal.SIGINT):
    signal.signal(_signum, _stop)
