"""analyze.py's modules, one concern each: data (the run folders and evaluate.py's per_seed.csv
to arrays), estimators (every estimate), figures (every figure), report (what the reports write).
"""
