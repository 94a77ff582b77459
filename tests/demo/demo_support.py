"""pytest helpers of the demo tests (a uniquely named module: the test dirs have no __init__.py)."""

from __future__ import annotations

import os

import pytest

from demo_stack import DemoStack

# A hash of the picture the <img> shows now (same origin, so the canvas may read it).
FRAME_HASH = """(() => {
  const img = document.getElementById('stream');
  if (!img.naturalWidth) return null;
  const canvas = document.createElement('canvas');
  canvas.width = img.naturalWidth; canvas.height = img.naturalHeight;
  const ctx = canvas.getContext('2d');
  ctx.drawImage(img, 0, 0);
  const data = ctx.getImageData(0, 0, canvas.width, canvas.height).data;
  let h = 0;
  for (let i = 0; i < data.length; i += 41) h = (Math.imul(h, 31) + data[i]) | 0;
  return h;
})()"""

IN_CI = os.environ.get("CI", "").lower() == "true"


def need(problem: str | None) -> None:
    """Skip (fail in CI) when PROBLEM says something this test needs is missing."""
    if problem:
        if IN_CI:
            pytest.fail(problem, pytrace=False)
        pytest.skip(problem)


def start_stack(request: pytest.FixtureRequest, **settings: str) -> DemoStack:
    """A running demo for the requesting module, torn down (with its logs shown on failure) at its end."""
    stack = DemoStack(**settings)
    failed_before = request.session.testsfailed

    def finish() -> None:
        if request.session.testsfailed > failed_before:
            print(f"\n--- logs of {stack.project} ---\n{stack.logs()}")
        stack.down()

    request.addfinalizer(finish)
    stack.up()
    stack.keep_a_prober()
    return stack
