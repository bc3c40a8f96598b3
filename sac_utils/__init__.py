"""What the scripts at the top import, each module owning one thing: cli (the command line: each
flag's range, --resume's rules, --env-id, the one-line error), run_folder (RunFolder: the run
folder from start to finish), checkpoints (what a checkpoint holds and the exact resume; old
weight layouts), restart (the restart from a snapshot, for sweep.py), eval_rounds (evaluation
rounds as jobs, beside training or in evaluate.py), speedups (torch.compile at start-up, CUDA
graphs, the compiled update: the scripts' own losses' gradients in one graph), files (written
whole or not at all), sweep_run (one run of a sweep.py grid), policies (what evaluate.py loads:
our weights or an SB3 SAC, as our Actor and TwinQ).
docs/scripts.md describes them; the analysis is analysis/'s (docs/analyze.md).
"""
