"""crane-collect: 4-channel bilateral control of two CRANE-X7 arms and crash-safe HDF5 sessions."""
