"""The optimisers: the batched augmented Lagrangian and SLSQP."""
