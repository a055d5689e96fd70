"""The simulated CRANE-X7: a chain of emulated X-series servos that answers real Protocol 2.0
bytes, backed by a plant (the physics). Users rehearse with it; tests run the real client on it."""
