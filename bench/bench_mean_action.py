"""Accuracy of mode_search.mean_action against scipy's adaptive quad, by number of nodes.

Run from the repository root: `python bench/bench_mean_action.py [--cases 4000]`. Over the
tests' cases (|mu| <= 20, sigma log-uniform in [1e-4, 10], plus the corners: sigma 1e-4 at and
near the kink, |mu| = 20, the bimodal sigma 1-3, sigma 10) it prints the largest absolute error
of the quadrature with each MEAN_NODES, and, for comparison, of plain Gauss-Hermite on tanh.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
import mode_search  # noqa: E402
from tests.test_mode_search import mean_cases, quad_mean  # noqa: E402


def gauss_hermite_mean(mu: np.ndarray, sigma: np.ndarray, nodes: int) -> np.ndarray:
    """The method that fails at large sigma: Gauss-Hermite straight on tanh(mu + sigma z)."""
    z, w = np.polynomial.hermite_e.hermegauss(nodes)
    return np.tanh(mu[:, None] + sigma[:, None] * z) @ w / math.sqrt(2.0 * math.pi)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=4000, help="random (mu, sigma) cases")
    cases = parser.parse_args().cases
    mu, sigma = mean_cases(cases, seed=10)
    reference = np.array([quad_mean(m, s) for m, s in zip(mu, sigma, strict=True)])
    print(f"{mu.size} cases; largest |error| against quad, and where (mu, sigma)")
    default = mode_search.MEAN_NODES
    for nodes in (16, 20, 24, 28, 32, 40, 48):
        mode_search.MEAN_NODES = nodes
        mean = mode_search.mean_action(torch.from_numpy(mu), torch.from_numpy(np.log(sigma)))
        report(f"mean_action, {nodes:3d} nodes per half-line", mean.numpy() - reference, mu, sigma)
    mode_search.MEAN_NODES = default
    for nodes in (60, 180):
        error = gauss_hermite_mean(mu, sigma, nodes) - reference
        report(f"plain Gauss-Hermite, {nodes:3d} nodes", error, mu, sigma)


def report(name: str, error: np.ndarray, mu: np.ndarray, sigma: np.ndarray) -> None:
    worst = np.abs(error).argmax()
    print(f"{name}: {abs(error[worst]):.1e} at ({mu[worst]:.3g}, {sigma[worst]:.3g})")


if __name__ == "__main__":
    main()
