"""The paper's two filters, discretised with the bilinear (Tustin) transform.

* pseudo-differentiation  D(s) = g s / (s + g)   (a derivative seen through a first-order lag)
* first-order low-pass     L(s) = w / (s + w)

With g = w the discrete pseudo-derivative equals the Tustin differentiator times the discrete
low-pass, so "derivative then one low-pass" and "two low-passes" carry exactly the same phase lag:
this is what lets the preprocessing give q, dq, ddq and tau the same delay.

Causal filtering (the paper) uses `scipy.signal.lfilter` started in steady state for the first
sample; the zero-phase option uses `scipy.signal.filtfilt` (no delay at all, magnitude squared).
All functions filter along axis 0 of a (N,) or (N, J) array.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy import signal


@lru_cache(maxsize=64)
def lowpass_coefficients(cutoff_rad_s: float, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """(b, a) of the discrete first-order low-pass w/(s+w) (the same arrays for the same arguments:
    read, never written)."""
    return signal.bilinear([cutoff_rad_s], [1.0, cutoff_rad_s], fs=rate_hz)


def pseudo_diff_coefficients(cutoff_rad_s: float, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """(b, a) of the discrete pseudo-differentiator g s/(s+g)."""
    return signal.bilinear([cutoff_rad_s, 0.0], [1.0, cutoff_rad_s], fs=rate_hz)


def _apply(b, a, x: np.ndarray, zero_phase: bool) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if zero_phase:
        padlen = min(3 * max(len(a), len(b)), x.shape[0] - 1)
        return signal.filtfilt(b, a, x, axis=0, padlen=padlen)
    zi = signal.lfilter_zi(b, a)  # steady-state initial conditions for a unit step input
    zi = zi.reshape((-1,) + (1,) * (x.ndim - 1)) * x[:1]
    y, _ = signal.lfilter(b, a, x, axis=0, zi=zi)
    return y


def lowpass(x: np.ndarray, cutoff_rad_s: float, rate_hz: float, zero_phase: bool = False) -> np.ndarray:
    """First-order low-pass along axis 0."""
    b, a = lowpass_coefficients(cutoff_rad_s, rate_hz)
    return _apply(b, a, x, zero_phase)


def pseudo_diff(x: np.ndarray, cutoff_rad_s: float, rate_hz: float, zero_phase: bool = False) -> np.ndarray:
    """Filtered derivative g s/(s+g) along axis 0 (units of x per second).

    The causal filter starts as if x had been constant before the first sample (output 0).
    """
    b, a = pseudo_diff_coefficients(cutoff_rad_s, rate_hz)
    if zero_phase:
        # forward-backward would cancel the derivative's sign on the backward pass; instead take the
        # exact central difference and smooth it with the zero-phase low-pass of the same cutoff.
        x = np.asarray(x, dtype=float)
        dx = np.gradient(x, 1.0 / rate_hz, axis=0)
        return _apply(*lowpass_coefficients(cutoff_rad_s, rate_hz), dx, True)
    x = np.asarray(x, dtype=float)
    # steady state for a constant input x[0] (output 0)
    zi_unit = signal.lfilter_zi(b, a)
    zi = zi_unit.reshape((-1,) + (1,) * (x.ndim - 1)) * x[:1]
    y, _ = signal.lfilter(b, a, x, axis=0, zi=zi)
    return y
