"""Influencing agents (paper §6.2): select worlds with a property, retrain on them, compare.

``parse_selection("crash_rate > 0.5")`` reads the property; ``influence(...)`` runs the
experiment end to end, cached in a run directory; ``reports.influence.influence_figure`` draws
Figure 8.
"""

from worldagent.influence.experiment import COMPARED, influence, load_influenced_worlds, select_worlds
from worldagent.influence.selection import Clause, Selection, parse_selection

__all__ = ["COMPARED", "Clause", "Selection", "influence", "load_influenced_worlds", "parse_selection", "select_worlds"]
