"""Names of the training methods. Light on purpose (no numpy, no torch): the command line's help and
option choices read it; train.models.registry and train.evaluation.sweep take their names from here."""

from __future__ import annotations

# every method `crane-train fit --model` accepts (train.models.registry maps each to its class)
METHOD_NAMES = ("rigid-body", "mlp-mse", "mlp-masked", "hybrid")
# the methods of the paper's sample-size sweep (train.evaluation.sweep)
SWEEP_METHODS = ("rigid-body", "mlp-mse", "mlp-masked")
