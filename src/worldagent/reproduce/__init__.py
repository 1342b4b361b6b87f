"""``worldagent reproduce``: the paper's experiments end to end, cached phase by phase in a run directory."""
