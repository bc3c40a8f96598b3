import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from mode_search import GRID_STEP, mean_action, mode_action, tanh_normal_log_prob

DTYPES = [torch.float32, torch.float64]
DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
LOG_STD_RANGE = (math.log(1e-6), math.log(10.0))


def random_params(n: int, seed: int, mu_scale: float = 3.0) -> tuple[torch.Tensor, torch.Tensor]:
    """(mu, log_std) in float64: mu ~ N(0, mu_scale) clipped to |mu| <= 20, sigma log-uniform."""
    g = torch.Generator().manual_seed(seed)
    mu = (mu_scale * torch.randn(n, generator=g, dtype=torch.float64)).clamp(-20.0, 20.0)
    log_std = torch.empty(n, dtype=torch.float64).uniform_(*LOG_STD_RANGE, generator=g)
    return mu, log_std


def bisection_mode(mu: torch.Tensor, log_std: torch.Tensor) -> torch.Tensor:
    """Reference mode: bisect x - |mu| - 2 sigma^2 tanh(x) on [|mu|, |mu| + 2 sigma^2], float64.

    That function is negative left of its one positive root and positive right of it.
    """
    m, c = mu.abs(), 2.0 * torch.exp(2.0 * log_std)
    lo, hi = m.clone(), m + c
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        below = mid - m - c * torch.tanh(mid) < 0
        lo, hi = torch.where(below, mid, lo), torch.where(below, hi, mid)
    return torch.copysign(torch.tanh(0.5 * (lo + hi)), mu)


def near_double_root_params() -> tuple[torch.Tensor, torch.Tensor]:
    """The hard corner for Newton: sigma near 1/sqrt(2) (c = 2 sigma^2 near 1), |mu| small."""
    c = 1.0 + torch.cat(
        [-torch.logspace(-14, -0.3, 60), torch.zeros(1), torch.logspace(-14, 0, 60)]
    )
    m = torch.cat([torch.zeros(1), torch.logspace(-14, 0, 60)])
    c, m = torch.meshgrid(c.double(), m.double(), indexing="ij")
    return m.reshape(-1), 0.5 * torch.log(c.reshape(-1) / 2.0)


def quad_mean(mu: float, sigma: float) -> float:
    """Reference E[tanh(u)], u ~ N(mu, sigma^2): scipy's adaptive quad in z = (u - mu) / sigma
    over [-12, 12] (the mass beyond: 4e-33), told where tanh's step at u = 0 lies."""
    from scipy import integrate

    def integrand(z: float) -> float:
        return math.tanh(mu + sigma * z) * math.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)

    kink = -mu / sigma
    points = [kink] if abs(kink) < 12 else None
    value, _ = integrate.quad(
        integrand, -12.0, 12.0, points=points, epsabs=1e-13, epsrel=1e-12, limit=500
    )
    return value


def mean_cases(n_random: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(mu, sigma): log-uniform sigma in [1e-4, 10] with |mu| <= 20, plus the corners: sigma
    1e-4 (with mu at and near the kink), |mu| = 20, the bimodal sigma 1-3, sigma 10."""
    g = np.random.default_rng(seed)
    mu = np.concatenate([g.uniform(-20, 20, n_random // 4), g.normal(0, 2, n_random)])
    sigma = np.exp(g.uniform(math.log(1e-4), math.log(10.0), mu.size))
    corner_mu = np.array([0.0, 1e-4, -3e-4, 0.25, 0.5, 1.0, 2.0, -2.0, 20.0, -20.0])
    corner_sigma = np.array([1e-4, 3e-4, 1.0, 1.5, 2.0, 3.0, 8.0, 10.0])
    grid_mu, grid_sigma = np.meshgrid(corner_mu, corner_sigma)
    mu = np.concatenate([mu, grid_mu.ravel()]).clip(-20, 20)
    return mu, np.concatenate([sigma, grid_sigma.ravel()])


# --- the density ---------------------------------------------------------------------------


@pytest.mark.parametrize("mu, sigma", [(0.0, 0.5), (1.0, 0.5), (-1.5, 0.3), (0.2, 1.0), (0.0, 1.5)])
def test_density_integrates_to_one(mu: float, sigma: float) -> None:
    y = torch.linspace(-1, 1, 400_001, dtype=torch.float64)[1:-1]
    p = tanh_normal_log_prob(y, torch.tensor(mu), torch.tensor(math.log(sigma))).exp()
    assert torch.trapezoid(p, y).item() == pytest.approx(1.0, abs=1e-4)


@pytest.mark.parametrize("mu, sigma", [(1.0, 0.5), (-0.5, 0.8), (0.0, 1.5)])
def test_density_matches_histogram_of_squashed_samples(mu: float, sigma: float) -> None:
    n, bins = 400_000, 40
    g = torch.Generator().manual_seed(0)
    y = torch.tanh(mu + sigma * torch.randn(n, generator=g, dtype=torch.float64))
    counts = torch.histc(y, bins=bins, min=-1.0, max=1.0)
    # Expected bin probabilities by fine quadrature of the density inside each bin.
    edges = torch.linspace(-1, 1, bins + 1, dtype=torch.float64)
    fine = torch.linspace(0, 1, 2001, dtype=torch.float64)[1:-1]
    pts = edges[:-1, None] + (edges[1:] - edges[:-1])[:, None] * fine
    log_p = tanh_normal_log_prob(pts, torch.tensor(mu), torch.tensor(math.log(sigma)))
    expected = log_p.exp().mean(dim=1) * (2.0 / bins) * n
    # 5 Poisson standard errors per bin: far above sampling noise, far below a wrong density.
    assert torch.all((counts - expected).abs() <= 5.0 * expected.sqrt() + 5.0)


def test_log_prob_matches_textbook_formula_where_that_is_accurate() -> None:
    y = torch.linspace(-0.99, 0.99, 397, dtype=torch.float64)
    mu, sigma = 0.3, 0.7
    gaussian = -0.5 * ((torch.atanh(y) - mu) / sigma) ** 2 - math.log(
        sigma * math.sqrt(2 * math.pi)
    )
    textbook = gaussian - torch.log(1 - y**2)
    log_std = torch.tensor(math.log(sigma), dtype=torch.float64)
    torch.testing.assert_close(tanh_normal_log_prob(y, torch.tensor(mu), log_std), textbook)


@pytest.mark.parametrize("dtype", DTYPES)
def test_log_prob_is_finite_inside_and_minus_inf_outside(dtype: torch.dtype) -> None:
    top = torch.nextafter(torch.tensor(1.0, dtype=dtype), torch.tensor(0.0, dtype=dtype))
    inside = torch.tensor([-top, -0.9999, -0.5, 0.0, 1e-30, 0.5, 0.9999, top], dtype=dtype)
    mu = torch.tensor([-20.0, -1.0, 0.0, 1.0, 20.0], dtype=dtype)[:, None, None]
    log_std = torch.tensor(LOG_STD_RANGE, dtype=dtype)[:, None]
    assert torch.isfinite(tanh_normal_log_prob(inside, mu, log_std)).all()
    outside = torch.tensor([-math.inf, -2.0, -1.0, 1.0, 1.0 + 1e-3, math.inf], dtype=dtype)
    assert (tanh_normal_log_prob(outside, mu, log_std) == -math.inf).all()


def test_log_prob_near_one_agrees_between_float32_and_float64() -> None:
    # 1 - y^2 computed naively loses all digits near 1 in float32; the module's form does not.
    y32 = 1.0 - torch.tensor([2.0**-24, 2.0**-20, 2.0**-12])
    args = (torch.tensor(3.0), torch.tensor(0.5))
    lp32 = tanh_normal_log_prob(y32, *args)
    lp64 = tanh_normal_log_prob(y32.double(), *(a.double() for a in args))
    torch.testing.assert_close(lp32.double(), lp64, rtol=1e-5, atol=0)


def test_log_prob_of_nan_is_nan() -> None:
    assert torch.isnan(
        tanh_normal_log_prob(torch.tensor(math.nan), torch.tensor(0.0), torch.tensor(0.0))
    )


# --- the mode ------------------------------------------------------------------------------


@pytest.mark.parametrize("solver", ["exact", "grid"])
@pytest.mark.parametrize(
    "mu, sigma, mode",
    [(1.0, 0.5, 0.8952), (-1.0, 0.5, -0.8952), (0.2, 1.0, 0.9730), (1.5, 0.6, 0.9759)],
)
def test_known_modes(solver: str, mu: float, sigma: float, mode: float) -> None:
    y = mode_action(torch.tensor(mu, dtype=torch.float64), torch.tensor(math.log(sigma)), solver)
    assert y.item() == pytest.approx(mode, abs=3e-4)


def test_bimodal_at_zero_mean_returns_one_of_the_two_symmetric_modes() -> None:
    # mu = 0, sigma = 1: modes at about +-0.957 of equal density, y = 0 is a minimum.
    for solver in ("exact", "grid"):
        y = mode_action(torch.tensor(0.0, dtype=torch.float64), torch.tensor(0.0), solver)
        assert abs(y.item()) == pytest.approx(0.9575, abs=3e-4)


def test_exact_matches_bisection_to_1e6_over_the_whole_range() -> None:
    mu, log_std = random_params(50_000, seed=1)
    hard_mu, hard_log_std = near_double_root_params()
    mu, log_std = (
        torch.cat([mu, hard_mu, -hard_mu]),
        torch.cat([log_std, hard_log_std, hard_log_std]),
    )
    err = (mode_action(mu, log_std) - bisection_mode(mu, log_std)).abs()
    assert err.max().item() <= 1e-6


def test_exact_is_the_global_maximum_of_a_dense_search() -> None:
    # Independent of the solver's theory: search x = artanh(y) on both sides of zero.
    mu, log_std = random_params(200, seed=2, mu_scale=1.0)
    mu, log_std = mu[:, None], log_std[:, None]
    span = mu.abs() + 2.0 * torch.exp(2.0 * log_std) + 1.0
    x = span * torch.linspace(-1, 1, 20_001, dtype=torch.float64)
    best_dense = tanh_normal_log_prob(torch.tanh(x), mu, log_std).max(dim=1).values
    at_exact = tanh_normal_log_prob(mode_action(mu, log_std), mu, log_std)[:, 0]
    assert torch.all(at_exact >= best_dense - 1e-9 * best_dense.abs().clamp(min=1.0))


@pytest.mark.parametrize("dtype", DTYPES)
def test_exact_is_never_worse_than_grid(dtype: torch.dtype) -> None:
    mu, log_std = random_params(2500, seed=3, mu_scale=1.5)
    # Plenty of bimodal cases (2 sigma^2 > 1) and near-ties between the two modes.
    mu = torch.cat([mu, 0.05 * mu]).to(dtype)
    log_std = torch.cat([log_std, torch.empty_like(log_std).uniform_(-0.5, 1.0)]).to(dtype)
    lp_exact = tanh_normal_log_prob(mode_action(mu, log_std, "exact"), mu, log_std)
    lp_grid = tanh_normal_log_prob(mode_action(mu, log_std, "grid"), mu, log_std)
    rounding = 1e3 * torch.finfo(dtype).eps * lp_grid.abs().clamp(min=1.0)
    assert torch.all(lp_exact >= lp_grid - rounding)
    assert (2.0 * torch.exp(2.0 * log_std) > 1.0).sum() > 1000


def test_grid_and_exact_agree_within_grid_resolution_where_mode_is_unique() -> None:
    mu, log_std = random_params(3000, seed=4, mu_scale=1.0)
    unimodal = 2.0 * torch.exp(2.0 * log_std) <= 1.0
    exact = mode_action(mu, log_std, "exact")
    in_range = exact.abs() < 0.999
    mu, log_std, exact = (
        mu[unimodal & in_range],
        log_std[unimodal & in_range],
        exact[unimodal & in_range],
    )
    assert mu.numel() > 1000
    grid = mode_action(mu, log_std, "grid")
    assert (grid - exact).abs().max().item() <= GRID_STEP * (1 + 1e-6)


def test_grid_returns_points_of_the_paper_grid_strictly_inside() -> None:
    mu, log_std = random_params(500, seed=5)
    y = mode_action(mu, log_std, "grid")
    index = (y + 0.999) / GRID_STEP
    torch.testing.assert_close(index, index.round(), rtol=0, atol=1e-6)
    assert y.abs().max().item() < 1.0 and y.max().item() == pytest.approx(0.9998)


@pytest.mark.parametrize("dtype", DTYPES)
def test_small_sigma_gives_tanh_mu(dtype: torch.dtype) -> None:
    mu = torch.linspace(-3, 3, 61, dtype=dtype)
    # The mode's pre-image is mu + 2 sigma^2 tanh(.), 2e-12 away from mu at sigma = 1e-6.
    y = mode_action(mu, torch.full_like(mu, math.log(1e-6)))
    atol = max(1e-11, 2 * torch.finfo(dtype).eps)
    torch.testing.assert_close(y, torch.tanh(mu), rtol=0, atol=atol)
    assert torch.all(y.abs() >= torch.tanh(mu).abs())


def test_exact_is_odd_in_mu() -> None:
    mu, log_std = random_params(10_000, seed=6)
    assert torch.equal(mode_action(-mu, log_std), -mode_action(mu, log_std))


def test_mode_moves_away_from_tanh_mu_towards_the_boundary_in_the_unimodal_regime() -> None:
    mu, log_std = random_params(10_000, seed=7, mu_scale=1.0)
    unimodal = 2.0 * torch.exp(2.0 * log_std) <= 1.0
    y = mode_action(mu, log_std)[unimodal]
    tanh_mu = torch.tanh(mu[unimodal])
    assert torch.all(torch.sign(y) == torch.sign(tanh_mu)) and torch.all(y.abs() >= tanh_mu.abs())


@pytest.mark.parametrize("solver", ["exact", "grid"])
@pytest.mark.parametrize("dtype", DTYPES)
def test_extreme_inputs_give_finite_modes_inside(solver: str, dtype: torch.dtype) -> None:
    mu = torch.tensor([-20.0, -5.0, -1e-30, 0.0, 1e-30, 5.0, 20.0], dtype=dtype)[:, None]
    log_std = torch.tensor([*LOG_STD_RANGE, 0.0, -0.5 * math.log(2.0)], dtype=dtype)
    y = mode_action(mu, log_std, solver)
    assert torch.isfinite(y).all() and (y.abs() < 1).all()


@pytest.mark.parametrize("dtype", DTYPES)
def test_mode_beyond_dtype_resolution_is_the_nearest_value_inside(dtype: torch.dtype) -> None:
    top = torch.nextafter(torch.tensor(1.0, dtype=dtype), torch.tensor(0.0, dtype=dtype))
    y = mode_action(
        torch.tensor([20.0, -20.0], dtype=dtype), torch.tensor(math.log(10.0), dtype=dtype)
    )
    assert torch.equal(y, torch.stack([top, -top]))


def test_infinite_mu_gives_the_nearest_value_inside() -> None:
    top = torch.nextafter(torch.tensor(1.0), torch.tensor(0.0))
    y = mode_action(torch.tensor([math.inf, -math.inf]), torch.tensor([-1.0, 1.0]))
    assert torch.equal(y, torch.stack([top, -top]))


@pytest.mark.parametrize("solver", ["exact", "grid"])
def test_nan_in_gives_nan_out_only_where_nan(solver: str) -> None:
    mu = torch.tensor([math.nan, 1.0, 1.0, 0.5])
    log_std = torch.tensor([0.0, math.nan, -1.0, -1.0])
    y = mode_action(mu, log_std, solver)
    assert torch.isnan(y[:2]).all() and torch.isfinite(y[2:]).all()


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("solver", ["exact", "grid"])
@pytest.mark.parametrize("dtype", DTYPES)
def test_shape_dtype_device_and_broadcasting(solver: str, dtype: torch.dtype, device: str) -> None:
    mu = torch.randn(4, 3, 61, dtype=dtype, device=device)
    log_std = torch.linspace(-2, 1, 61, dtype=dtype, device=device)
    y = mode_action(mu, log_std, solver)
    assert y.shape == (4, 3, 61) and y.dtype == dtype and y.device == mu.device
    assert mode_action(mu[0, 0, 0], log_std[0], solver).shape == ()
    # Each element depends only on its own (mu, log_std): broadcasting equals explicit expansion.
    torch.testing.assert_close(y, mode_action(mu, log_std.expand_as(mu).clone(), solver))
    assert mode_action(mu[:0], log_std, solver).shape == (0, 3, 61)


def test_mode_does_not_track_gradients() -> None:
    mu = torch.randn(5, requires_grad=True)
    assert not mode_action(mu, torch.zeros(5)).requires_grad


def test_unknown_solver_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match="solver must be 'exact' or 'grid'"):
        mode_action(torch.zeros(3), torch.zeros(3), solver="newton")


def test_integer_mu_is_a_clear_error() -> None:
    with pytest.raises(TypeError, match="floating-point"):
        mode_action(torch.zeros(3, dtype=torch.int64), torch.zeros(3))


def test_mode_solves_the_stationarity_condition() -> None:
    # Stationarity: the mode's pre-image solves x = mu + 2 sigma^2 tanh(x).
    mu, sigma = np.array([1.0, 0.2, 1.5]), np.array([0.5, 1.0, 0.6])
    y = mode_action(torch.from_numpy(mu), torch.from_numpy(np.log(sigma))).numpy()
    x = np.arctanh(y)
    np.testing.assert_allclose(x, mu + 2 * sigma**2 * np.tanh(x), atol=1e-9)


# --- the mean ------------------------------------------------------------------------------


def test_mean_matches_quad_over_the_whole_range() -> None:
    mu, sigma = mean_cases(400, seed=0)
    reference = torch.tensor(
        [quad_mean(m, s) for m, s in zip(mu, sigma, strict=True)], dtype=torch.float64
    )
    mean = mean_action(torch.from_numpy(mu), torch.from_numpy(np.log(sigma)))
    # The docstring promises 1e-10; plain Gauss-Hermite (180 nodes) misses by 2e-3 at sigma 8.
    assert (mean - reference).abs().max().item() <= 1e-9
    assert ((sigma > 1) & (np.abs(mu) < 3)).sum() > 50


@pytest.mark.parametrize("dtype", DTYPES)
def test_mean_at_tiny_sigma_is_tanh_mu(dtype: torch.dtype) -> None:
    mu = torch.cat([torch.linspace(-20, 20, 81), torch.tensor([1e-4, -1e-4, 0.0])]).to(dtype)
    mean = mean_action(mu, torch.full_like(mu, math.log(1e-4)))
    # E[tanh u] - tanh(mu) ~ tanh''(mu) sigma^2 / 2, and |tanh''| <= 0.77.
    atol = max(0.77 * 1e-8 / 2, 2 * torch.finfo(dtype).eps)
    torch.testing.assert_close(mean, torch.tanh(mu), rtol=0, atol=atol)


def test_mean_of_a_point_mass_is_tanh_mu() -> None:
    mu = torch.tensor([-2.0, 0.0, 0.5], dtype=torch.float64)
    torch.testing.assert_close(mean_action(mu, torch.full_like(mu, -math.inf)), torch.tanh(mu))


def test_mean_lies_between_zero_and_the_median_tanh_mu() -> None:
    # Pairing mu + d with mu - d: tanh(mu + d) + tanh(mu - d) lies in [0, 2 tanh(mu)] for mu >= 0.
    mu, sigma = mean_cases(2000, seed=1)
    mu, log_std = torch.from_numpy(mu), torch.from_numpy(np.log(sigma))
    signed = torch.sign(mu) * mean_action(mu, log_std)
    assert torch.all(signed >= -1e-15) and torch.all(signed <= torch.tanh(mu).abs() + 1e-15)
    assert torch.equal(mean_action(-mu, log_std), -mean_action(mu, log_std))


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", DTYPES)
def test_mean_shape_dtype_device_and_broadcasting(dtype: torch.dtype, device: str) -> None:
    mu = 3.0 * torch.randn(3, 4, 5, dtype=dtype, device=device)
    log_std = torch.linspace(math.log(1e-4), math.log(10.0), 5, dtype=dtype, device=device)
    mean = mean_action(mu, log_std)
    assert mean.shape == (3, 4, 5) and mean.dtype == dtype and mean.device == mu.device
    torch.testing.assert_close(mean, mean_action(mu, log_std.expand_as(mu).clone()))
    # float32 in, float64 inside: the float32 result is the float64 one rounded.
    in_float64 = mean_action(mu.double(), log_std.double())
    torch.testing.assert_close(mean.double(), in_float64, rtol=0, atol=2 * torch.finfo(dtype).eps)
    assert mean_action(mu[0, 0, 0], log_std[0]).shape == ()
    assert mean_action(mu[:0], log_std).shape == (0, 4, 5)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_mean_on_cuda_equals_the_cpu_result() -> None:
    mu, sigma = mean_cases(400, seed=2)
    mu, log_std = torch.from_numpy(mu), torch.from_numpy(np.log(sigma))
    on_gpu = mean_action(mu.cuda(), log_std.cuda())
    assert on_gpu.is_cuda
    torch.testing.assert_close(on_gpu.cpu(), mean_action(mu, log_std), rtol=0, atol=1e-13)


def test_mean_nan_in_gives_nan_out_only_where_nan() -> None:
    mu = torch.tensor([math.nan, 1.0, 1.0, 0.5])
    log_std = torch.tensor([0.0, math.nan, -1.0, -1.0])
    mean = mean_action(mu, log_std)
    assert torch.isnan(mean[:2]).all() and torch.isfinite(mean[2:]).all()


def test_mean_of_integer_mu_is_a_clear_error() -> None:
    with pytest.raises(TypeError, match="floating-point"):
        mean_action(torch.zeros(3, dtype=torch.int64), torch.zeros(3))


@pytest.mark.slow
def test_figures_command_writes_the_six_pngs(tmp_path) -> None:
    root = Path(__file__).resolve().parent.parent
    out = subprocess.run(
        [sys.executable, str(root / "docs" / "make_figures.py"), "theory", "--out",
         str(tmp_path / "figs")],
        capture_output=True,
        text=True,
        check=True,
        cwd=tmp_path,
    )
    written = sorted(Path(line) for line in out.stdout.split())
    assert [p.name for p in written] == [
        "fig1_gaussian_vs_tanh.png",
        "fig2_distribution_shift.png",
        "fig3_action_bias.png",
        "fig4_2d_example.png",
        "fig5_shift_vs_dimensions.png",
        "fig6_mode_median_mean.png",
    ]
    assert all(p.read_bytes().startswith(b"\x89PNG") and p.stat().st_size > 10_000 for p in written)
