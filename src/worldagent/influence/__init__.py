"""Influencing agents (paper §6.2): select worlds with a property, retrain on them, compare.

``parse_selection("crash_rate > 0.5")`` reads the property; ``influence(...)`` runs the
experiment end to end, cached in a run directory (``experiments.influence`` is the usual entry
point); ``reports.influence.influence_figure`` draws Figure 8.
"""

from worldagent.events import Clause, Selection, parse_selection
from worldagent.influence.cache import load_influenced_worlds
from worldagent.influence.experiment import influence
from worldagent.influence.worlds import select_worlds

__all__ = ["Clause", "Selection", "influence", "load_influenced_worlds", "parse_selection", "select_worlds"]
