"""Fourier projections of records (eq. 3.3): one record and many at once."""

from __future__ import annotations

import numpy as np
import pytest

from bifid.errors import BifidInputError
from bifid.signal import (
    fourier_basis,
    fourier_project,
    fourier_project_batch,
    fourier_project_segments,
)


def _records(rng: np.random.Generator, lengths: list[int], q: int):
    """Padded phases, samples and true coefficients of records ``x = c0 + Σ a cos + b sin``."""
    n = max(lengths)
    coef = rng.normal(size=(len(lengths), 2 * q + 1, 2))
    B = np.zeros((len(lengths), n, 2 * q + 1))
    x = np.zeros((len(lengths), n, 2))
    for i, m in enumerate(lengths):
        theta = 0.3 * i + 2.0 * np.pi * np.arange(m) / 97.0
        B[i, :m] = fourier_basis(theta, q)
        x[i, :m] = B[i, :m] @ coef[i]
    return B, x, coef


def test_batch_recovers_exact_coefficients_of_padded_records():
    rng = np.random.default_rng(0)
    B, x, coef = _records(rng, [97, 96, 98, 97], 5)
    c = fourier_project_batch(x, B)
    np.testing.assert_allclose(c, coef, rtol=0, atol=1e-12)
    c1 = fourier_project_batch(x[..., 0], B)  # one signal per record
    np.testing.assert_allclose(c1, coef[..., 0], rtol=0, atol=1e-12)


def test_batch_equals_one_record_at_a_time_with_weights_and_noise():
    rng = np.random.default_rng(1)
    lengths = [97, 96, 98]
    B, x, _ = _records(rng, lengths, 3)
    x = x + 0.1 * rng.normal(size=x.shape)
    w = rng.uniform(0.5, 2.0, size=x.shape[:2])
    for i, m in enumerate(lengths):
        x[i, m:] = 0.0  # padding: zero rows in x as in B
    c = fourier_project_batch(
        x, B, weights=w * (np.arange(x.shape[1])[None, :] < np.array(lengths)[:, None])
    )
    for i, m in enumerate(lengths):
        one = fourier_project(x[i, :m], None, 3, weights=w[i, :m], basis=B[i, :m])
        np.testing.assert_allclose(c[i], one, rtol=1e-12, atol=1e-14)


def test_batch_falls_back_to_least_squares_for_singular_records():
    # 3 samples, 5 unknowns: normal equations singular, minimum-norm least squares instead
    rng = np.random.default_rng(2)
    B, x, _ = _records(rng, [97, 3], 2)
    c = fourier_project_batch(x[..., 0], B)
    expect = np.linalg.lstsq(B[1, :3], x[1, :3, 0], rcond=None)[0]
    np.testing.assert_allclose(c[1], expect, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(B[1, :3] @ c[1], x[1, :3, 0], atol=1e-12)


def test_segments_recover_each_periods_own_coefficients():
    # a record whose series changes from period to period (amplitude and mean drift)
    fs, omega, q = 1000.0, 7.0, 4
    per = 2.0 * np.pi / omega * fs
    n = round(6 * per)
    t = np.arange(n) / fs
    theta = omega * t
    edges = [round(k * per) for k in range(7)]
    rng = np.random.default_rng(3)
    coef = rng.normal(size=(6, 2 * q + 1))
    x = np.empty(n)
    for k in range(6):
        lo, hi = edges[k], edges[k + 1]
        x[lo:hi] = fourier_basis(theta[lo:hi], q) @ coef[k]
    c, resid = fourier_project_segments(x, theta, edges, q)
    np.testing.assert_allclose(c, coef, rtol=0, atol=1e-11)
    assert resid.shape == (n,) and np.max(np.abs(resid)) < 1e-11


def test_segments_equal_one_fit_per_segment_on_noisy_records():
    fs, omega, q = 500.0, 5.0, 6
    per = 2.0 * np.pi / omega * fs
    rng = np.random.default_rng(4)
    n = round(5 * per)
    theta = 0.7 + omega * np.arange(n) / fs
    x = np.column_stack([np.sin(theta) ** 3, np.cos(2 * theta)]) + 0.05 * rng.normal(size=(n, 2))
    edges = [round(k * per) for k in range(6)]
    c, resid = fourier_project_segments(x, theta, edges, q)
    for k in range(5):
        lo, hi = edges[k], edges[k + 1]
        one = fourier_project(x[lo:hi], theta[lo:hi], q)
        np.testing.assert_allclose(c[k], one, rtol=1e-10, atol=1e-13)
        fitted = fourier_basis(theta[lo:hi], q) @ one
        np.testing.assert_allclose(resid[lo:hi], x[lo:hi] - fitted, rtol=0, atol=1e-12)


def test_segments_reject_phases_of_varying_step():
    theta = np.cumsum(np.linspace(0.01, 0.02, 300))
    with pytest.raises(BifidInputError):
        fourier_project_segments(np.sin(theta), theta, [0, 150, 300], 2)
