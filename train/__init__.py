"""crane-train: session reader, filters, dead-zone masks, models, losses, sweep, diagnosis, reports."""
