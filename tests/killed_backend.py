"""A backend that stands in for a process killed mid-run (tests of resuming)."""

from __future__ import annotations

from worldagent.evaluation.backends import LocalBackend


class DiesAfter(LocalBackend):
    """A backend whose process is 'killed' after ``batches`` batches."""

    def __init__(self, batches: int):
        self.left = batches

    def run(self, evaluate, batches):
        for item in super().run(evaluate, batches):
            if self.left == 0:
                raise KeyboardInterrupt
            self.left -= 1
            yield item
