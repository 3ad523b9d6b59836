"""Trajectory refinement (§3.4.3): filters, acceleration violations, interpolate and re-solve, the cap."""

import numpy as np
import pytest

from solver import SolverError
from solver.retarget.refine import (
    E_ACC,
    MAX_ITERATIONS,
    PATIENCE,
    acceleration,
    hampel,
    interpolate_gaps,
    lowpass,
    refine_trajectory,
    remaining_work,
)
from solver.retarget.spline import fit_bspline

FPS = 120.0
F = 360
LENGTH = 0.19  # a human hand's length: translations are measured in it


def _smoothstep(t, t0, duration, amplitude):
    s = np.clip((t - t0) / duration, 0.0, 1.0)
    return amplitude * s**3 * (s * (6 * s - 15) + 10)


@pytest.fixture(scope="module")
def truth():
    """A smooth 5-DOF motion: a root translation (metres), then four angles, with accelerations up to
    ~110 rad/s² (a 1.2 rad curl in 0.25 s): real hand motion, far below the threshold."""
    t = np.arange(F) / FPS
    theta = np.stack(
        [
            _smoothstep(t, 0.4, 0.6, 0.25),
            _smoothstep(t, 0.8, 0.3, 1.0) - _smoothstep(t, 2.2, 0.3, 1.0),
            _smoothstep(t, 1.0, 0.25, 1.2),
            0.1 * np.sin(2 * np.pi * 1.5 * t),
            0.3 + 0.05 * t,
        ],
        axis=1,
    )
    return theta


ROT = np.array([False, True, True, True, True])
SCALE = np.where(ROT, 1.0, 1.0 / LENGTH)


class Recorder:
    """A toy re-solve: returns ground truth (plus optional per-call noise) and records its calls."""

    def __init__(self, truth, noise=None):
        self.truth = truth
        self.noise = noise
        self.calls = []

    def __call__(self, frames, seeds):
        self.calls.append((frames.copy(), seeds.copy()))
        out = self.truth[frames].copy()
        if self.noise is not None:
            out += self.noise(len(self.calls), frames)
        return out


# ------------------------------------------------------------------------------------ building blocks


def test_acceleration_of_a_parabola_is_exact():
    t = np.arange(10) / FPS
    theta = np.stack([3.5 * t**2, -2.0 * t**2 + t], 1)
    np.testing.assert_allclose(acceleration(theta, FPS), np.tile([7.0, -4.0], (10, 1)), rtol=1e-9)
    assert np.all(acceleration(theta[:2], FPS) == 0)


def test_interpolate_gaps_is_linear_between_nearest_kept_neighbours():
    x = np.array([[0.0, 5.0], [9.0, 9.0], [9.0, 6.0], [3.0, 9.0], [4.0, 9.0]])
    keep = np.array([[1, 1], [0, 0], [0, 1], [1, 0], [1, 0]], bool)
    out = interpolate_gaps(x, keep)
    np.testing.assert_allclose(out[:, 0], [0.0, 1.0, 2.0, 3.0, 4.0])
    np.testing.assert_allclose(out[:, 1], [5.0, 5.5, 6.0, 6.0, 6.0])  # constant past the last kept frame


def test_hampel_removes_a_peak_and_keeps_ramps_and_extrema():
    t = np.arange(40) / FPS
    x = np.stack([0.5 * t, np.cos(2 * np.pi * 2 * t)], 1)
    spiked = x.copy()
    spiked[17, 0] += 0.3
    out, replaced = hampel(spiked, floor=1e-6)
    assert np.argwhere(replaced).tolist() == [[17, 0]]
    untouched = ~replaced
    np.testing.assert_array_equal(out[untouched], x[untouched])
    # The spike becomes its window's median: on a ramp, one frame's step from the true value.
    assert abs(out[17, 0] - x[17, 0]) <= 0.5 / FPS + 1e-15


def test_lowpass_is_zero_phase_and_passes_slow_motion():
    t = np.arange(F) / FPS
    ramp = np.stack([0.2 + 0.7 * t, np.sin(2 * np.pi * 0.5 * t)], 1)
    out = lowpass(ramp, FPS, cutoff=10.0)
    np.testing.assert_allclose(out[:, 0], ramp[:, 0], atol=1e-9)  # linear motion passes exactly
    assert np.abs(out[:, 1] - ramp[:, 1]).max() < 1e-3  # 0.5 Hz: gain 1, no lag
    noisy = np.sin(2 * np.pi * 30 * t)  # above the cutoff: removed
    assert np.abs(lowpass(noisy[:, None], FPS, cutoff=10.0)[20:-20]).max() < 0.02


# ------------------------------------------------------------------------------------ the refinement


def test_clean_trajectory_passes_untouched(truth):
    resolve = Recorder(truth)
    r = refine_trajectory(truth, FPS, ROT, resolve, length=LENGTH)
    assert resolve.calls == []
    np.testing.assert_array_equal(r.theta, truth)
    assert r.valid.all()
    assert r.log.violations == (0,) and r.log.converged and r.log.resolves == 0 and r.log.peaks == 0
    # ... although the motion accelerates: its peak is real motion, well under the threshold.
    peak = np.abs(acceleration(truth, FPS) * SCALE).max()
    assert 100 < peak < E_ACC


def test_spikes_are_removed_by_the_filters_and_resolved_to_truth(truth):
    spikes = [(50, 1, 0.2), (120, 2, -0.3), (121, 3, 0.25), (200, 0, 0.01), (300, 4, 0.5)]
    noisy = truth.copy()
    for f, j, v in spikes:
        noisy[f, j] += v
    resolve = Recorder(truth)
    r = refine_trajectory(noisy, FPS, ROT, resolve, length=LENGTH)
    np.testing.assert_array_equal(r.theta, truth)
    assert r.log.converged and r.valid.all()
    assert r.log.peaks == len(spikes)  # the peak filter caught every spike
    assert set(f for f, _, _ in spikes) <= set(r.log.prefilter_frames.tolist())
    assert r.log.violations == (0,)  # nothing left for the iterations


def test_a_single_spike_flags_exactly_three_frames_of_one_dof(truth):
    f, j, delta = 100, 2, 0.05  # second differences: +δ, -2δ, +δ (× fps² = 720, 1440, 720 rad/s²)
    noisy = truth.copy()
    noisy[f, j] += delta
    resolve = Recorder(truth)
    r = refine_trajectory(noisy, FPS, ROT, resolve, length=LENGTH, prefilter=False)
    assert r.log.violations == (3, 0)
    assert len(r.log.resolved_frames) == 1
    np.testing.assert_array_equal(r.log.resolved_frames[0], [f - 1, f, f + 1])
    _, seeds = resolve.calls[0]
    # Seeds: the flagged DOF linearly interpolated between frames f-2 and f+2, the others untouched.
    expected = noisy[f - 1 : f + 2].copy()
    expected[:, j] = noisy[f - 2, j] + (np.arange(1, 4) / 4) * (noisy[f + 2, j] - noisy[f - 2, j])
    np.testing.assert_allclose(seeds, expected, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(r.theta, truth)


def test_threshold_counts_between_one_and_two_times_the_spike(truth):
    # δ fps² < e_acc < 2 δ fps²: only the spike's own frame violates.
    delta = 0.75 * E_ACC / FPS**2
    noisy = truth.copy()
    noisy[150, 3] += delta
    resolve = Recorder(truth)
    r = refine_trajectory(noisy, FPS, ROT, resolve, length=LENGTH, prefilter=False)
    assert r.log.violations == (1, 0)
    np.testing.assert_array_equal(r.log.resolved_frames[0], [150])


def test_translations_are_measured_in_hand_lengths(truth):
    delta = 0.02  # metres
    noisy = truth.copy()
    noisy[90, 0] += delta  # second differences 2 δ fps² = 576 m/s² and δ fps² = 288 m/s²
    for length, flagged in ((0.5, 3), (1.0, 1), (2.0, 0)):  # 576/L and 288/L against 349
        resolve = Recorder(truth)
        r = refine_trajectory(noisy, FPS, ROT, resolve, length=length, prefilter=False)
        assert r.log.violations[0] == flagged, length


def test_noisy_resolves_converge(truth):
    rng = np.random.default_rng(4)
    noisy = truth.copy()
    noisy[[40, 41, 250], [1, 1, 3]] += [0.1, -0.1, 0.2]
    sigma = 1e-4

    def noise(call, frames):
        return sigma * rng.standard_normal((len(frames), truth.shape[1]))

    resolve = Recorder(truth, noise)
    r = refine_trajectory(noisy, FPS, ROT, resolve, length=LENGTH, prefilter=False)
    assert r.log.converged and r.valid.all()
    assert r.log.iterations == 1
    assert np.abs(r.theta - truth).max() < 6 * sigma


def test_shrinking_noise_takes_a_predictable_number_of_iterations(truth):
    f, j, delta = 180, 1, 0.1
    noisy = truth.copy()
    noisy[f, j] += delta

    def noise(call, frames):  # the re-solve lands at a spike that halves with each call
        out = np.zeros((len(frames), truth.shape[1]))
        out[frames == f, j] = delta * 0.5**call
        return out

    resolve = Recorder(truth, noise)
    r = refine_trajectory(noisy, FPS, ROT, resolve, length=LENGTH, prefilter=False)
    # Spike δ_k = δ / 2^k: 3 flagged while δ_k fps² > e, 1 while only 2 δ_k fps² > e, then 0.
    expected = []
    k = 0
    while True:
        d = delta * 0.5**k * FPS**2
        expected.append(3 if d > E_ACC else (1 if 2 * d > E_ACC else 0))
        if expected[-1] == 0:
            break
        k += 1
    assert r.log.violations == tuple(expected) == (3, 3, 3, 1, 0)
    assert r.log.converged


def test_iteration_stops_at_the_cap_and_masks_what_is_left(truth):
    f, j, delta = 70, 2, 0.2

    def stubborn(call, frames):  # a local minimum every re-solve falls back into
        out = np.zeros((len(frames), truth.shape[1]))
        out[frames == f, j] = delta
        return out

    noisy = truth.copy()
    noisy[f, j] += delta
    # By default, rounds that change nothing end the refinement after PATIENCE of them, long before the
    # cap; with min_progress = 0 (the paper's rule) it runs to the cap.
    stopped = refine_trajectory(noisy, FPS, ROT, Recorder(truth, stubborn), length=LENGTH, prefilter=False)
    assert stopped.log.iterations == PATIENCE < MAX_ITERATIONS
    assert stopped.log.stalled and not stopped.log.converged
    assert len(set(stopped.log.excess)) == 1 and stopped.log.excess[0] > 0
    resolve = Recorder(truth, stubborn)
    r = refine_trajectory(
        noisy, FPS, ROT, resolve, length=LENGTH, prefilter=False, max_iterations=4, min_progress=0.0
    )
    assert r.log.iterations == 4 and len(resolve.calls) == 4
    assert r.log.violations == (3, 3, 3, 3, 3) and not r.log.converged and not r.log.stalled
    np.testing.assert_array_equal(stopped.valid, r.valid)
    assert r.log.unresolved.tolist() == [[f - 1, j], [f, j], [f + 1, j]]
    expected = np.ones_like(r.valid)
    expected[f - 1 : f + 2, j] = False
    np.testing.assert_array_equal(r.valid, expected)

    # The fit ignores what is masked: the spline through the rest does not see the spike.
    fit = fit_bspline(r.theta, 60, valid=r.valid, fps=FPS)
    assert np.abs(fit.values - truth).max() < 0.01 < delta

    r0 = refine_trajectory(noisy, FPS, ROT, Recorder(truth), length=LENGTH, prefilter=False, max_iterations=0)
    assert r0.log.iterations == 0 and r0.log.violations == (3,) and (~r0.valid).sum() == 3


def test_progress_can_stop_early(truth):
    noisy = truth.copy()
    noisy[60, 1] += 0.2
    seen = []

    def progress(done, total):
        seen.append((done, total))
        return True

    r = refine_trajectory(noisy, FPS, ROT, Recorder(truth), length=LENGTH, prefilter=False, progress=progress)
    assert seen == [(1, 21)] and r.log.cancelled and r.log.iterations == 0
    assert (~r.valid).sum() == 3


def test_angle_wrap(truth):
    """A root angle turning through ±π, wrapped by the solver, is one smooth curve; seeds stay on the
    solver's branch."""
    t = np.arange(F) / FPS
    turning = 2.5 + 0.9 * t  # passes π at t ≈ 0.71 s and keeps going
    wrapped = np.mod(turning + np.pi, 2 * np.pi) - np.pi
    theta = truth.copy()
    theta[:, 4] = wrapped
    resolve = Recorder(theta)
    clean = refine_trajectory(theta, FPS, ROT, resolve, length=LENGTH)
    assert resolve.calls == [] and clean.log.violations == (0,)
    np.testing.assert_allclose(clean.theta[:, 4], turning, atol=1e-12)  # returned unwrapped

    wrap_frame = int(np.flatnonzero(np.diff(wrapped) < 0)[0]) + 1
    noisy = theta.copy()
    noisy[wrap_frame, 4] += 0.3  # a spike right at the wrap
    resolve = Recorder(theta)
    r = refine_trajectory(noisy, FPS, ROT, resolve, length=LENGTH, prefilter=False)
    assert r.log.converged and r.log.violations == (3, 0)
    np.testing.assert_allclose(r.theta[:, 4], turning, atol=1e-12)
    frames, seeds = resolve.calls[0]
    # Every seed is on the branch of its frame's solve: within the spike of it, never 2π away.
    assert np.abs(seeds[:, 4] - noisy[frames, 4]).max() < 0.5
    assert np.all(np.abs(seeds[:, 4]) <= np.pi + 0.5)


def test_failed_solves_are_interpolated_and_resolved(truth):
    noisy = truth.copy()
    noisy[[30, 31]] = np.nan
    noisy[200, 2] = np.inf
    r = refine_trajectory(noisy, FPS, ROT, Recorder(truth), length=LENGTH)
    assert r.log.nonfinite == 2 * truth.shape[1] + 1
    assert {30, 31, 200} <= set(r.log.prefilter_frames.tolist())
    np.testing.assert_array_equal(r.theta, truth)
    assert r.valid.all()

    def failing(frames, seeds):  # a solve that keeps failing leaves its entries masked
        out = truth[frames].copy()
        out[frames == 30] = np.nan
        return out

    r = refine_trajectory(noisy, FPS, ROT, failing, length=LENGTH, max_iterations=2)
    assert not r.valid[30].any() and r.valid[31].all() and np.isfinite(r.theta).all()


def test_bad_input_is_refused(truth):
    with pytest.raises(SolverError, match="is_rotation"):
        refine_trajectory(truth, FPS, ROT[:3], Recorder(truth), length=LENGTH)
    with pytest.raises(SolverError, match="length"):
        refine_trajectory(truth, FPS, ROT, Recorder(truth), length=0.0)
    bad = truth.copy()
    bad[:, 2] = np.nan
    with pytest.raises(SolverError, match="DOFs 2") as err:
        refine_trajectory(bad, FPS, ROT, Recorder(truth), length=LENGTH)
    assert err.value.dofs.tolist() == [2]
    noisy = truth.copy()
    noisy[50, 1] += 0.5
    with pytest.raises(SolverError, match="resolve returned shape"):
        refine_trajectory(noisy, FPS, ROT, lambda f, s: s[:, :2], length=LENGTH)


def test_the_estimate_of_later_rounds_follows_how_they_shrink():
    assert remaining_work([], 5) == 0 and remaining_work([40], 0) == 0
    assert remaining_work([40], 3) == pytest.approx(40 * (0.5 + 0.25 + 0.125))  # no history: halving
    assert remaining_work([40, 10], 2) == pytest.approx(10 * (0.25 + 0.0625))  # shrinking by 4
    # Rounds that hardly shrink end within PATIENCE more (the stopping rule), however many are allowed.
    assert remaining_work([40, 39], 18) == 39 * PATIENCE
