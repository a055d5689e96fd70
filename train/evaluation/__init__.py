"""How good is a model, or a session: the held-out data a model is judged on (heldout), per-joint error
metrics (metrics), models side by side (compare), the HTML report (report), the paper's sample-size
experiment (sweep), the figures (plots), and the force channel's fidelity of a bilateral session
(fidelity)."""
