"""Tools around the labels: replay on the arm (more to come: show, report, export, evaluate)."""
