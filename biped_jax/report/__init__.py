"""Output files, run manifests, compile profiles and the XLA alarm filter."""
