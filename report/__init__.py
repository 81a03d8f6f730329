"""REPORT.md's content: the paper's numbers (paper.py) and the header, tables, claims and wall times that set
ours beside them (tables.py), and the figures (figures.py, strip.py). Knows the paper, not how a run is made:
run_all calls it with the stages' results and a run's policies."""
