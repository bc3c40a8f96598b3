"""The mode of a tanh-squashed Gaussian, the action Corrected SAC evaluates with.

SAC samples u ~ N(mu, sigma^2) per action dimension and acts with y = tanh(u). The density of y
(the paper's Eq. 6) is p(y) = N(artanh(y); mu, sigma^2) / (1 - y^2). Three actions summarise
that distribution per dimension, and they differ:
- tanh(mu), what standard SAC evaluates with, is its MEDIAN: tanh is monotone, so
  P(y <= tanh(mu)) = P(u <= mu) = 1/2.
- The mode, argmax_y p(y), is the paper's choice (Corrected SAC); it moves from tanh(mu) towards
  +-1 as sigma grows.
- The mean E[tanh(u)] moves the other way, towards 0: tanh flattens the tails.

This module computes the density, the mode and the mean, per dimension, on torch tensors of any
batch shape (mu and log_std broadcast), float32 or float64, CPU or CUDA.

- `tanh_normal_log_prob(y, mu, log_std)`: log p(y), -inf outside (-1, 1).
- `mode_action(mu, log_std, solver="exact")`: argmax_y p(y). "grid" is the paper's Algorithm 1;
  "exact" solves the stationarity condition with a fixed number of vectorised Newton steps.
- `mean_action(mu, log_std)`: E[tanh(u)] by quadrature, to 1e-10 or better.
- NaN in mu or log_std gives NaN out (the mode or mean of an undefined distribution is undefined).

`python docs/make_figures.py theory --out DIR` draws the paper's theory figures from it.
"""

from __future__ import annotations

import functools
import math

import torch

# Algorithm 1 of the paper: y_i = -0.999 + 0.0004 i, i = 0..5000. Taken literally the grid runs
# to 1.001; the points with |y| >= 1 lie outside the density's domain and are dropped.
GRID_START = -0.999
GRID_STEP = 0.0004
GRID_POINTS = 5001
# Grid evaluations held in memory at once (rows x grid points): 32 MiB of float64.
GRID_CHUNK_ELEMENTS = 2**22
# Newton steps of the exact solver. Over |mu| <= 20, sigma in [1e-6, 10] (bench/bench_mode_search.py
# measures it against bisection) 3 steps leave 2e-5 in y, 4 leave 4e-10, 5 leave float64 rounding.
NEWTON_STEPS = 5
_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)
# Gauss-Legendre nodes per half-line of mean_action. Against scipy's adaptive quad over
# |mu| <= 20, sigma in [1e-4, 10] (docs/mode.md; measured by bench/bench_mean_action.py, in git
# history: `git show 65bdc88:bench/bench_mean_action.py`) the largest error is 4e-5 with
# 20 nodes, 6e-7 with 24, 3e-11 with 32 and the reference's own 1e-13 from 40 on.
MEAN_NODES = 32
# The Gaussian is cut at +-8.5 sigma (the mass beyond: 2e-17) and the remainder tanh - sign at
# |u| = 20, where it is 2 e^-40 = 8e-18.
MEAN_GAUSS_CUT = 8.5
MEAN_REMAINDER_CUT = 20.0


def tanh_normal_log_prob(y: torch.Tensor, mu: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    """Elementwise log-density of y = tanh(u), u ~ N(mu, exp(log_std)^2); -inf outside (-1, 1).

    Stable up to |y| = the largest float below 1: artanh(y) and log(1 - y^2) are both built from
    log1p(y) and log1p(-y), and 1 - y is exact for y near 1, so neither rounds to inf or 0.
    """
    log1p_y, log1m_y = torch.log1p(y), torch.log1p(-y)
    x = 0.5 * (log1p_y - log1m_y)
    z = (x - mu) * torch.exp(-log_std)
    log_p = -0.5 * z * z - log_std - _HALF_LOG_2PI - (log1p_y + log1m_y)
    # At |y| = 1 the expression is inf - inf; a NaN y still fails the test and stays NaN.
    return torch.where(y.abs() >= 1, -math.inf, log_p)


@torch.no_grad()
def mode_action(mu: torch.Tensor, log_std: torch.Tensor, solver: str = "exact") -> torch.Tensor:
    """The mode of tanh(N(mu, exp(log_std)^2)) per dimension, in (-1, 1).

    Returns a tensor with mu's dtype and device and the broadcast shape of mu and log_std. When
    the mode lies closer to +-1 than the dtype resolves, returns the nearest value inside.
    solver: "exact" (Newton on the stationarity condition, to 1e-6 or better) or "grid" (the
    paper's Algorithm 1, resolution 0.0004, |y| <= 0.9998).
    """
    if solver not in ("exact", "grid"):
        raise ValueError(f"solver must be 'exact' or 'grid', got {solver!r}")
    mu, log_std = torch.as_tensor(mu), torch.as_tensor(log_std)
    if not mu.is_floating_point():
        raise TypeError(f"mu must be a floating-point tensor, got {mu.dtype}; pass mu.float()")
    y = _exact_mode(mu, log_std) if solver == "exact" else _grid_mode(mu, log_std)
    inside = 1.0 - torch.finfo(mu.dtype).eps / 2  # the largest float below 1
    return y.to(mu.dtype).clamp(-inside, inside)


def _exact_mode(mu: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    """Global mode via its pre-image x = artanh(y), computed in float64.

    log p(tanh x) = -(x - mu)^2 / (2 sigma^2) - log(1 - tanh(x)^2) + const, so stationary points
    solve g(x) = x - m - c tanh(x) = 0 with m = |mu|, c = 2 sigma^2 (taking m = |mu| and restoring
    the sign at the end is exact: the density is odd-symmetric in mu). Three facts make a fixed
    number of Newton steps enough:
    - log p(tanh x) - log p(tanh -x) = 2 x m / sigma^2 > 0 for x > 0, so the global mode has the
      sign of mu: no comparison between the two modes of the bimodal regime (c > 1) is needed.
    - On x > 0, g is convex with g(0) = -m <= 0: it has exactly one positive root r (the mode),
      m <= r < m + c, and Newton converges to it monotonically from the right of r, and from
      the left (above the minimum of g) overshoots once to the right.
    - Where r is small (sigma near 1/sqrt(2), |mu| small: nearly a double root, slow for Newton)
      tanh x >= x - x^3/3 bounds g by the cubic (c/3)(x^3 - a x - b), a = 3(c-1)/c, b = 3m/c,
      whose root lies just below r and is at least (max(a, 0)^1.5 + b)^(1/3). Newton starts
      there when that is below 1, else from m + c.
    """
    # An infinite |mu| becomes a huge finite one, whose mode rounds to the largest float below 1.
    m = mu.to(torch.float64).abs().clamp(max=1e300)
    c = torch.exp(2.0 * log_std.to(torch.float64) + math.log(2.0))
    three_over_c = 3.0 / c
    a, b = 3.0 - three_over_c, m * three_over_c
    cubic_root = (a.clamp(min=0.0) ** 1.5 + b) ** (1.0 / 3.0)
    x = torch.where(cubic_root < 1.0, cubic_root, m + c)
    # + 1e-300 keeps g' nonzero where it vanishes at the root (mu = 0, c = 1; g = 0 there too).
    slope_at_zero = (1.0 - c) + 1e-300
    for _ in range(NEWTON_STEPS):
        t = torch.tanh(x)
        g = torch.addcmul(x - m, c, t, value=-1.0)
        g_prime = torch.addcmul(slope_at_zero, c, t * t)
        x = torch.addcdiv(x, g, g_prime, value=-1.0)
    return torch.copysign(torch.tanh(x), mu)


@torch.no_grad()
def mean_action(mu: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    """E[tanh(u)], u ~ N(mu, exp(log_std)^2), per dimension: the mean of the squashed policy.

    Returns a tensor with mu's dtype and device and the broadcast shape of mu and log_std,
    computed in float64; absolute error below 1e-10 over |mu| <= 20, sigma in [1e-4, 10] (float32
    output: its rounding). sigma = 0 gives tanh(mu); NaN in gives NaN out.

    Plain Gauss-Hermite on tanh fails at large sigma: on the Gaussian's scale tanh is then a step
    at u = 0 (180 nodes leave 2e-3 at sigma ~ 8). The step's part is exact,
    E[sign u] = erf(mu / (sqrt(2) sigma)), and what is left, tanh u - sign u = -sign(u) r(|u|)
    with r(v) = 1 - tanh v = 2 / (1 + e^(2v)), is smooth on each half-line:
        E[tanh u] = erf(mu / (sqrt(2) sigma)) - (H(mu) - H(-mu)),
        H(c) = integral over v > 0 of r(v) N(v; c, sigma^2) dv.
    H is integrated by MEAN_NODES-point Gauss-Legendre over the part of [0, 20] within 8.5 sigma
    of c, so the nodes follow the Gaussian at small sigma and r's decay at large sigma. r's
    poles lie on the imaginary axis (v = i pi/2 + i k pi), next to the interval's end at 0,
    where Legendre's nodes cluster, which is why so few nodes suffice.
    """
    mu, log_std = torch.as_tensor(mu), torch.as_tensor(log_std)
    if not mu.is_floating_point():
        raise TypeError(f"mu must be a floating-point tensor, got {mu.dtype}; pass mu.float()")
    mu64, sigma = torch.broadcast_tensors(mu.to(torch.float64), log_std.to(torch.float64).exp())
    step = torch.erf(mu64 / (math.sqrt(2.0) * sigma))
    mean = step - (_half_line_remainder(mu64, sigma) - _half_line_remainder(-mu64, sigma))
    # At sigma = 0 the quadrature divides 0 by 0; the distribution is a point mass at tanh(mu).
    mean = torch.where(sigma == 0, torch.tanh(mu64), mean)
    return mean.to(mu.dtype)


def _half_line_remainder(center: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """H(c) of mean_action: integral over v > 0 of (1 - tanh v) N(v; c, sigma^2) dv."""
    nodes, weights = _legendre(MEAN_NODES, center.device)
    low = (center - MEAN_GAUSS_CUT * sigma).clamp(0.0, MEAN_REMAINDER_CUT)
    high = (center + MEAN_GAUSS_CUT * sigma).clamp(0.0, MEAN_REMAINDER_CUT)
    half_width = (0.5 * (high - low)).unsqueeze(-1)
    v = (0.5 * (low + high)).unsqueeze(-1) + half_width * nodes
    z = (v - center.unsqueeze(-1)) / sigma.unsqueeze(-1)
    # 1 - tanh v = 2 sigmoid(-2 v), which keeps its relative precision where it is tiny.
    integrand = 2.0 * torch.sigmoid(-2.0 * v) * torch.exp(-0.5 * z * z)
    integral = (half_width * integrand * weights).sum(dim=-1)
    return integral / (sigma * math.sqrt(2.0 * math.pi))


@functools.cache
def _legendre(n: int, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """Gauss-Legendre nodes and weights on [-1, 1] in float64 (Golub-Welsch: the eigenvalues of
    the Jacobi matrix), made once per device so mode_search needs no numpy or scipy."""
    k = torch.arange(1, n, dtype=torch.float64)
    off_diagonal = k / torch.sqrt(4.0 * k * k - 1.0)
    jacobi = torch.diag(off_diagonal, 1) + torch.diag(off_diagonal, -1)
    nodes, vectors = torch.linalg.eigh(jacobi)
    weights = 2.0 * vectors[0] ** 2
    return nodes.to(device), weights.to(device)


@functools.cache
def _grid(dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """Algorithm 1's grid points inside (-1, 1), made once per dtype and device: a CUDA graph
    that captures the grid solver then copies nothing from the host."""
    grid = GRID_START + GRID_STEP * torch.arange(GRID_POINTS, dtype=torch.float64)
    return grid[grid.abs() < 1].to(dtype=dtype, device=device)


def _grid_mode(mu: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    """The paper's Algorithm 1: argmax of the density over a fixed grid, first point on ties."""
    grid = _grid(mu.dtype, mu.device)
    mu, log_std = torch.broadcast_tensors(mu, log_std)
    flat_mu, flat_log_std = mu.reshape(-1, 1), log_std.reshape(-1, 1)
    rows = max(1, GRID_CHUNK_ELEMENTS // grid.numel())
    best = torch.empty_like(flat_mu[:, 0])
    for i in range(0, flat_mu.shape[0], rows):
        log_p = tanh_normal_log_prob(grid, flat_mu[i : i + rows], flat_log_std[i : i + rows])
        best[i : i + rows] = grid[log_p.argmax(dim=1)]
    best = best.reshape(mu.shape)
    # argmax over an all-NaN row would return a grid point; an undefined mode is NaN instead.
    return torch.where(torch.isnan(mu + log_std), math.nan, best)


# --- the summed shift over dimensions: docs/make_figures.py's fig5, analyze.py's dimension study
# A spread of per-dimension (mu, sigma) like a trained SAC policy's: SAC's entropy target of
# -|A|/2 nats puts a dimension's sigma near 0.15 (|mu| ~ 0) to 0.35 (|mu| ~ 1), so log sigma is
# drawn from U(-3, -0.5) (sigma 0.05 to 0.61) and mu from N(0, 1). An early-training spread
# (log sigma ~ U(-1, 0.5), sigma 0.37 to 1.65, partly bimodal) shows the other end.
SPREADS = {
    "trained policy: log sigma ~ U(-3, -0.5)": (-3.0, -0.5),
    "early training: log sigma ~ U(-1, 0.5)": (-1.0, 0.5),
}


def summed_shift_by_dimension(
    dims: int, log_std_range: tuple[float, float], draws: int = 1000, seed: int = 0
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Theory for fig5 and analyze.py's dimension study: sum over the first n dimensions of
    |mode - tanh(mu)|, mu ~ N(0, 1) and log sigma ~ U(log_std_range) per dimension; its mean and
    5-95% range over `draws` draws, for n = 1..dims."""
    generator = torch.Generator().manual_seed(seed)
    mu = torch.randn(draws, dims, generator=generator, dtype=torch.float64)
    log_std = torch.empty(draws, dims, dtype=torch.float64).uniform_(
        *log_std_range, generator=generator
    )
    shift = (mode_action(mu, log_std) - torch.tanh(mu)).abs().cumsum(dim=1)
    low, high = torch.quantile(shift, torch.tensor([0.05, 0.95], dtype=torch.float64), dim=0)
    return shift.mean(dim=0), low, high
