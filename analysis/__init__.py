"""analyze.py's modules, one concern each: data (run folders' eval.csv and evaluate.py's
per_seed.csv to arrays), estimators (every interval, bootstrap, aggregate and verdict; evaluate.py
uses them too), figures (every figure), report (summary.csv, summary.md and their cells).
docs/analyze.md maps each figure and table to the function that makes it.
"""
