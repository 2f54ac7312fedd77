"""One module per command-line study (``biped-jax <command>``)."""
