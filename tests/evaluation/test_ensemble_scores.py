"""The ensemble scores: the fair CRPS (docs/spec/long-rollouts.md#crps) against the closed form for
Gaussians, the spread/skill ratio and the rank histogram on synthetic calibrated, under- and
over-dispersed ensembles, and the ensemble mean across periodic and Lees-Edwards images."""

import math

import numpy as np
import pytest
import torch

from gripdem.boundary import Box, wrap_positions
from gripdem.evaluation.ensemble_scores import (
    crps_per_step,
    ensemble_mean_and_spread,
    fair_crps,
    pairwise_abs_sum,
    rank_flatness,
    rank_histogram,
    spread_skill_per_step,
)


def gaussian_crps(mu, sigma, y):
    """Closed form: sigma * (z (2 Phi(z) - 1) + 2 phi(z) - 1 / sqrt(pi)), z = (y - mu) / sigma."""
    z = (y - mu) / sigma
    phi = torch.exp(-0.5 * z**2) / math.sqrt(2 * math.pi)
    cdf = 0.5 * (1 + torch.erf(z / math.sqrt(2)))
    return sigma * (z * (2 * cdf - 1) + 2 * phi - 1 / math.sqrt(math.pi))


@pytest.mark.parametrize("members", [2, 3, 8])
def test_fair_crps_is_unbiased_for_the_gaussian_closed_form(members):
    """Members drawn from N(mu, sigma^2): the fair CRPS averaged over many truths equals the
    closed-form CRPS of the Gaussian (unbiased for every M, which the plain estimator is not:
    it exceeds the closed form by E|X - X'| / (2M))."""
    gen = torch.Generator().manual_seed(0)
    n = 400_000
    mu, sigma = torch.randn(n, generator=gen, dtype=torch.float64), 0.7
    truth = mu + torch.randn(n, generator=gen, dtype=torch.float64) * 1.3
    x = mu + sigma * torch.randn(members, n, generator=gen, dtype=torch.float64)
    estimate = fair_crps(x, truth)
    exact = gaussian_crps(mu, sigma, truth)
    difference = float((estimate - exact).mean())
    standard_error = float((estimate - exact).std()) / math.sqrt(n)
    assert abs(difference) < 4 * standard_error
    plain = (x - truth).abs().mean(0) - pairwise_abs_sum(x) / (2 * members**2)
    bias = sigma * 2 / math.sqrt(math.pi) / (2 * members)  # E|X - X'| / (2M)
    assert float((plain - exact).mean()) == pytest.approx(bias, rel=0.05)


def test_fair_crps_of_small_ensembles_in_closed_form():
    x = torch.tensor([[1.0, -2.0], [3.0, 0.5]], dtype=torch.float64)  # 2 members, 2 coordinates
    y = torch.tensor([2.0, 0.0], dtype=torch.float64)
    expected = torch.tensor([(1 + 1) / 2 - 2 / 2, (2 + 0.5) / 2 - 2.5 / 2], dtype=torch.float64)
    torch.testing.assert_close(fair_crps(x, y), expected)
    torch.testing.assert_close(fair_crps(x[:1], y), (x[0] - y).abs())  # M = 1: absolute error
    many = torch.randn(6, 50, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    brute = (many[:, None] - many[None]).abs().sum((0, 1))
    torch.testing.assert_close(pairwise_abs_sum(many), brute)


def synthetic(scale: float, members: int = 8, seed: int = 0):
    """Residuals ``(M, W, f, N, 3)`` of an ensemble whose members have ``scale`` times the
    spread of the truth around the forecast mean (1: calibrated)."""
    gen = torch.Generator().manual_seed(seed)
    shape = (20, 4, 500, 3)
    mean = torch.randn(shape, generator=gen, dtype=torch.float64)
    truth = mean + torch.randn(shape, generator=gen, dtype=torch.float64)
    x = mean + scale * torch.randn((members, *shape), generator=gen, dtype=torch.float64)
    return truth - x


def test_a_calibrated_ensemble_has_spread_skill_one_and_a_flat_rank_histogram():
    res = synthetic(1.0)
    np.testing.assert_allclose(spread_skill_per_step(res), 1.0, atol=0.02)
    top, bottom = rank_flatness(rank_histogram(res))
    assert top < 1.05 and bottom > 0.95


def test_an_under_dispersed_ensemble_fails_both():
    res = synthetic(0.3)
    assert np.all(spread_skill_per_step(res) < 0.5)
    hist = rank_histogram(res)
    top, _ = rank_flatness(hist)
    assert top > 1.5 and max(hist[0], hist[-1]) == hist.max()  # a U shape


def test_an_over_dispersed_ensemble_fails_both():
    res = synthetic(3.0)
    assert np.all(spread_skill_per_step(res) > 2.0)
    hist = rank_histogram(res)
    _, bottom = rank_flatness(hist)
    assert bottom < 0.5 and hist[0] < hist[len(hist) // 2]  # a dome: the ends are empty


def test_a_point_forecast_crps_is_its_mean_absolute_error():
    res = synthetic(1.0, members=1)[0]
    np.testing.assert_allclose(crps_per_step(res), res.abs().mean(dim=(0, 2, 3)).numpy())
    with pytest.raises(ValueError, match="at least 2 members"):
        spread_skill_per_step(res[None])


@pytest.mark.parametrize("offset", [None, 0.37])
def test_ensemble_mean_across_the_images(offset):
    """Members on both sides of a face (and of the LE x face) average to the right place."""
    box = Box.from_lengths([2.0, 2.0, 2.0])
    centre = np.array([[0.99, -0.99, 0.5]])  # near the +x and -y faces
    shifts = np.array([[0.02, 0.0, 0.0], [-0.02, 0.01, 0.0], [0.0, -0.01, 0.03]])
    members = wrap_positions(centre + shifts[:, None], box, offset)
    mean, spread = ensemble_mean_and_spread(members, box, offset)
    expected = wrap_positions(centre + shifts.mean(0), box, offset)
    np.testing.assert_allclose(mean, expected, atol=1e-12)
    np.testing.assert_allclose(spread, np.sqrt(shifts.var(0, ddof=1).sum())[None], atol=1e-12)
