"""``worldagent explore RUN_DIR``: a local web app over a run (see ``server.py`` and docs/explorer.md).

``session.py`` holds the run's worlds, generators and agents; ``views.py`` the pure functions
behind each view; ``server.py`` the FastAPI app; ``static/`` the page (no build step, no CDN).
"""
