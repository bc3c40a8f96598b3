"""What the scripts at the top import, each module owning one thing (its docstring says which):
cli, run_folder, checkpoints, eval_rounds, speedups and files for a run; restart, sweep_run and
policies for sweep.py and evaluate.py. docs/scripts.md describes them.
"""
