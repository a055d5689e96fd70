"""Fit a model from session files through the public API and save it, as `crane-train fit` does (the
tests' shorthand: train.fit(...).save(out_dir), returning the fit's metrics document)."""

from __future__ import annotations

import train


def fit_model(sessions, method: str, out_dir, *, progress: bool = False, **options) -> dict:
    """train.fit(sessions, method, **options) saved to out_dir; `progress` is accepted and ignored (the
    tests show no bars)."""
    result = train.fit(list(sessions), method, **options)
    result.save(out_dir)
    return result.metrics
