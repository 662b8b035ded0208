"""Integrated autocorrelation time of ensemble chains, vectorised (pure NumPy)."""

from __future__ import annotations

import numpy as np

__all__ = ["integrated_time"]


def integrated_time(x: np.ndarray, c: float = 5.0) -> np.ndarray:
    """Integrated autocorrelation time τ of an ensemble chain.

    The estimator of :func:`emcee.autocorr.integrated_time`: each walker's normalised
    autocorrelation function, averaged over walkers, summed up to Sokal's window (the first lag M
    with M ≥ c·τ(M)). Computed for all walkers and parameters with one real FFT instead of one
    complex FFT per walker and parameter.

    Parameters
    ----------
    x : (n_steps, n_walkers, ndim) or (n_steps, n_walkers)
    c : window constant

    Returns
    -------
    (ndim,) array, or a float for 2-D input; steps. A walker that never moved contributes no
    correlation beyond lag 0.
    """
    x = np.asarray(x, float)
    scalar = x.ndim == 2
    if scalar:
        x = x[..., None]
    if x.ndim != 3 or x.shape[0] < 2:
        raise ValueError(f"integrated_time: expected (n_steps ≥ 2, n_walkers[, ndim]), got {x.shape}")
    n = x.shape[0]
    n_fft = 1 << int(np.ceil(np.log2(2 * n)))
    # a walker that never moved (or moved by rounding only: a derived roll that is constant in
    # exact arithmetic) is exactly zero after centring; its mean can differ from its value in the
    # last bit, and that constant residue would read as perfect correlation
    still = np.ptp(x, axis=0) <= 1e-9 * np.maximum(1.0, np.max(np.abs(x), axis=0))
    centred = np.where(still, 0.0, x - x.mean(axis=0))
    f = np.fft.rfft(centred, n=n_fft, axis=0)
    acf = np.fft.irfft(f.real**2 + f.imag**2, n=n_fft, axis=0)[:n]
    with np.errstate(invalid="ignore", divide="ignore"):
        acf = acf / acf[0]
    acf = np.where(np.isfinite(acf), acf, 0.0)
    acf[0] = 1.0
    rho = acf.mean(axis=1)  # (n, ndim)
    taus = 2.0 * np.cumsum(rho, axis=0) - 1.0
    inside = np.arange(n)[:, None] < c * taus
    window = np.where(inside.all(axis=0), n - 1, np.argmin(inside, axis=0))
    tau = taus[window, np.arange(taus.shape[1])]
    return float(tau[0]) if scalar else tau
