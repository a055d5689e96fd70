"""Identification of the arm's rigid-body and friction parameters: weighted least squares with honest
uncertainties, the physically consistent projection and a verdict (`crane-train identify`)."""
