"""The contour task's tools: its experiment (``cheope demo``'s laps, the position-control comparison,
the per-lap report and plots: ``experiment.py``, ``report.py``), its scans against disturbances
(``scan.py``, ``stress.py``) and their commands (``commands.py``: ``cheope contour-scan``, ...), and
the force's answer to a hold-up of the loop in a recording (``holdup_response.py``)."""
