"""DONALD, the 4-DoF prototype: model and speed optimisation."""
