"""Defaults of the diagnosis, in a module of their own so that `crane-train diagnose --help` shows them
without importing the diagnosis (numpy and the effects library)."""

from __future__ import annotations

DEFAULT_FOLDS = 5  # cross-validation folds
DEFAULT_MIN_REDUCTION = 0.15  # a candidate must cut the held-out residual by this fraction
DEFAULT_MIN_FOLD_FRACTION = 1.0  # ... and lower the held-out error in this fraction of the folds
