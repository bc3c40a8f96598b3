"""The mode of a tanh-squashed Gaussian, the action Corrected SAC evaluates with.

SAC samples u ~ N(mu, sigma^2) per action dimension and acts with y = tanh(u). The density of y
(the paper's Eq. 6) is p(y) = N(artanh(y); mu, sigma^2) / (1 - y^2), and its mode is not
tanh(mu). This module computes that density and its mode, per dimension, on torch tensors of any
batch shape (mu and log_std broadcast), float32 or float64, CPU or CUDA.

- `tanh_normal_log_prob(y, mu, log_std)`: log p(y), -inf outside (-1, 1).
- `mode_action(mu, log_std, solver="exact")`: argmax_y p(y). "grid" is the paper's Algorithm 1;
  "exact" solves the stationarity condition with a fixed number of vectorised Newton steps.
- NaN in mu or log_std gives NaN out (the mode of an undefined distribution is undefined).

`python mode_search.py --figures DIR` writes the paper's theory figures as PNGs.
"""

from __future__ import annotations

import math

import torch

# Algorithm 1 of the paper: y_i = -0.999 + 0.0004 i, i = 0..5000. Taken literally the grid runs
# to 1.001; the points with |y| >= 1 lie outside the density's domain and are dropped.
GRID_START = -0.999
GRID_STEP = 0.0004
GRID_POINTS = 5001
# Grid evaluations held in memory at once (rows x grid points): 32 MiB of float64.
GRID_CHUNK_ELEMENTS = 2**22
# Newton steps of the exact solver. From its starting point 4 steps already reach 1e-8 in y over
# the whole range |mu| <= 20, sigma in [1e-6, 10] (tests/test_mode_search.py checks 1e-6 against
# bisection); the fifth is margin.
NEWTON_STEPS = 5
_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)


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
        raise TypeError(f"mu must be a floating-point tensor, got {mu.dtype}")
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
      tanh x ~ x - x^3/3 turns g into the cubic x^3 - a x - b, a = 3(c-1)/c, b = 3m/c, whose root
      is close to r, at least (max(a, 0)^1.5 + b)^(1/3). Newton starts there when that is below
      1, else from m + c.
    """
    m = mu.to(torch.float64).abs()
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


def _grid_mode(mu: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    """The paper's Algorithm 1: argmax of the density over a fixed grid, first point on ties."""
    grid = GRID_START + GRID_STEP * torch.arange(GRID_POINTS, dtype=torch.float64)
    grid = grid[grid.abs() < 1].to(dtype=mu.dtype, device=mu.device)
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
