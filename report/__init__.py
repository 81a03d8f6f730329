"""REPORT.md's content: the paper's numbers (paper.py) and the header, tables, claims and wall times that set
ours beside them (tables.py). Knows the paper, not how a run is made: run_all calls it with the stages' results."""
