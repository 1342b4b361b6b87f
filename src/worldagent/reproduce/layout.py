"""Where a ``reproduce`` run directory keeps each environment's outputs: ``worldagent.runs.RunLayout``.

The layout lives in ``runs.py``, below both the writer (``reproduce/``) and the readers
(``reports/``, ``explore/``); this name stays for the phases and older imports.
"""

from worldagent.runs import RunLayout

__all__ = ["RunLayout"]
