"""The optimisers: the batched interior point (exact autodiff derivatives), the batched augmented
Lagrangian and SLSQP."""
