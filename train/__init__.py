"""crane-train: session reader, filters, dead-zone masks, models, losses, sweep, diagnosis, reports.

The Python front door (train/api.py): `load_sessions`, `fit`, `load_model`, `diagnose_model`,
`discover_terms`, `compare_models`, `make_report`, `load_settings`; docs/examples/api_tour.py walks the
modelling loop with them."""

from .api import (
    FitResult,
    compare_models,
    diagnose_model,
    diagnosis_inputs,
    discover_terms,
    fit,
    load_model,
    load_sessions,
    load_settings,
    make_report,
)

__all__ = ["FitResult", "compare_models", "diagnose_model", "diagnosis_inputs", "discover_terms", "fit",
           "load_model", "load_sessions", "load_settings", "make_report"]
