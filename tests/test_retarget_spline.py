"""Cubic B-spline fit of DOF curves (§3.4.4): exactness, C², masks, control points, speed."""

import itertools
import time

import numpy as np
import pytest
from scipy.interpolate import make_lsq_spline

from solver import SolverError
from solver.retarget.spline import clamped_knots, fit_bspline, greville

FPS = 120.0


def _samples(F=300, d=4, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(F) / FPS
    smooth = np.stack([np.sin((k + 1) * 2.1 * t + k) for k in range(d)], 1)
    return t, smooth + 0.01 * rng.standard_normal((F, d))


def test_knots_and_greville_abscissae():
    knots = clamped_knots(0.0, 2.0, 7)
    np.testing.assert_allclose(knots, [0, 0, 0, 0, 0.5, 1.0, 1.5, 2, 2, 2, 2])
    np.testing.assert_allclose(greville(knots), [0, 1 / 6, 0.5, 1.0, 1.5, 11 / 6, 2.0])


@pytest.mark.parametrize("n_control", [4, 9, 30])
def test_cubic_polynomials_are_reproduced_exactly(n_control):
    F = 240
    t = np.arange(F) / FPS
    cubics = np.stack([1 + 2 * t - 3 * t**2 + 4 * t**3, -0.5 * t**3 + 0.2, 0.7 - 1.1 * t], 1)
    fit = fit_bspline(cubics, n_control, fps=FPS)
    np.testing.assert_allclose(fit.values, cubics, rtol=0, atol=1e-11)
    assert fit.residual.max() < 1e-11
    dense = np.linspace(0, t[-1], 1001)
    np.testing.assert_allclose(fit(dense)[:, 1], -0.5 * dense**3 + 0.2, atol=1e-11)
    # Control points sit at their locations in time: a linear function's control values are its
    # values at the Greville abscissae.
    np.testing.assert_allclose(fit.control[:, 2], 0.7 - 1.1 * fit.times, atol=1e-11)


def test_matches_an_independent_least_squares_fit():
    t, x = _samples()
    fit = fit_bspline(x, 25, fps=FPS)
    oracle = make_lsq_spline(t, x, fit.knots, k=3)
    np.testing.assert_allclose(fit.control, oracle.c, atol=1e-9)


def test_second_derivative_is_continuous_at_every_knot():
    t, x = _samples(seed=1)
    fit = fit_bspline(x, 20, fps=FPS)
    inner = np.unique(fit.knots)[1:-1]
    h = 1e-9
    left, right = fit(inner - h, nu=2), fit(inner + h, nu=2)
    scale = np.abs(fit(np.linspace(0, t[-1], 500), nu=2)).max()
    assert np.abs(right - left).max() < 1e-6 * scale
    # ... while the third derivative does jump there: these are genuine cubic pieces.
    jump3 = np.abs(fit(inner + h, nu=3) - fit(inner - h, nu=3))
    assert jump3.max() > 1e-2 * np.abs(fit(np.linspace(0, t[-1], 500), nu=3)).max()


def test_masked_samples_are_ignored_dof_by_dof():
    t, x = _samples(d=3, seed=2)
    rng = np.random.default_rng(3)
    valid = rng.random(x.shape) > 0.2
    valid[100:140, 1] = False  # a long gap in one DOF
    corrupted = np.where(valid, x, 1e6)
    corrupted[5, 0] = np.nan if not valid[5, 0] else corrupted[5, 0]
    fit = fit_bspline(corrupted, 18, valid=valid, fps=FPS)
    for j in range(3):
        keep = valid[:, j]
        oracle = make_lsq_spline(t[keep], x[keep, j], fit.knots, k=3)
        np.testing.assert_allclose(fit.control[:, j], oracle.c, atol=1e-8)
    assert np.isfinite(fit.values).all()


def test_gaps_without_data_are_bridged_smoothly():
    t = np.arange(400) / FPS
    x = np.sin(2 * t)[:, None]
    valid = np.ones_like(x, bool)
    valid[150:260] = False  # several control points see no sample at all
    fit = fit_bspline(x, 40, valid=valid, fps=FPS)
    assert np.isfinite(fit.control).all()
    keep = valid[:, 0]
    assert np.abs(fit.values[keep] - x[keep]).max() < 1e-3
    # The bridge stays between the values it joins, within a little overshoot.
    lo, hi = x[[149, 260], 0].min(), x[[149, 260], 0].max()
    bridge = fit.values[150:260, 0]
    assert lo - 0.5 < bridge.min() and bridge.max() < hi + 0.5


def test_fewer_samples_than_control_points_give_the_smoothest_interpolant():
    t = np.arange(300) / FPS
    x = np.sin(2 * t)[:, None]
    errors = []
    for k in (3, 5, 8, 15):
        valid = np.zeros_like(x, bool)
        valid[np.linspace(0, 299, k).astype(int)] = True
        fit = fit_bspline(x, 20, valid=valid, fps=FPS)
        assert np.isfinite(fit.values).all()
        assert np.abs(fit.values - x)[valid].max() < 1e-6  # through every sample
        errors.append(np.abs(fit.values - x).max())
    assert all(b < a for a, b in itertools.pairwise(errors)) and errors[-1] < 0.02


def test_more_control_points_fit_closer():
    _, x = _samples(d=2, seed=4)
    # Nested knot sets (each one's spans halve the previous one's): the residual must fall.
    residuals = [fit_bspline(x, n, fps=FPS).residual.max() for n in (5, 7, 11, 19, 35, 67)]
    assert all(b < a for a, b in itertools.pairwise(residuals))
    assert 0.008 < residuals[-1] < 0.0105  # down to the noise (σ = 0.01), not below it


def test_bad_input_is_refused():
    _, x = _samples()
    with pytest.raises(SolverError, match="n_control"):
        fit_bspline(x, 3)
    with pytest.raises(SolverError, match="n_control"):
        fit_bspline(x[:10], 11)
    valid = np.ones(x.shape, bool)
    valid[1:, 2] = False
    with pytest.raises(SolverError, match="DOFs 2") as err:
        fit_bspline(x, 10, valid=valid)
    assert err.value.dofs.tolist() == [2]
    with pytest.raises(SolverError, match="valid"):
        fit_bspline(x, 10, valid=valid[:, :2])


def test_thousand_frames_sixty_dofs_take_milliseconds():
    rng = np.random.default_rng(5)
    x = np.cumsum(rng.standard_normal((1000, 60)), axis=0) * 1e-3
    valid = rng.random(x.shape) > 0.02  # every DOF its own mask: the worst case
    for mask in (None, valid):
        fit_bspline(x, 120, valid=mask, fps=FPS)
        runs = []
        for _ in range(5):
            start = time.perf_counter()
            fit_bspline(x, 120, valid=mask, fps=FPS)
            runs.append(time.perf_counter() - start)
        assert np.median(runs) < 0.25  # measured: ~10 ms on the 2-core CI machine


@pytest.mark.parametrize("n_control", [0, -1, 2, 3, 4.0])
def test_retarget_options_refuse_a_control_count_the_spline_cannot_take_up_front(n_control):
    """Issue 39: checked when the options are made, not by the spline stage after every frame's solve; 0
    is refused, not taken for the default (None)."""
    from solver.retarget import RetargetOptions
    from solver.retarget.spline import DEGREE

    with pytest.raises(SolverError, match=f"n_control must be a whole number of at least {DEGREE + 1} "):
        RetargetOptions(n_control=n_control)
    assert RetargetOptions(n_control=DEGREE + 1).n_control == 4 and RetargetOptions().n_control is None
    with pytest.raises(SolverError, match="n_control"):  # what the spline itself needs: the same bound
        fit_bspline(_samples()[1], DEGREE)
