"""Inverse-dynamics models behind one interface (base.Model): the rigid-body physics model (rigid_body),
the paper's networks (mlp, trained by batched with the losses of losses), the hybrid of the two
(hybrid); the method names (method_names, light for `--help`) and the registry that maps them to classes
(registry); the effects a fitted model records (recorded_effects); the control loop's numeric export
(loop_export) and its one-sample predictor (fast_predict)."""
