"""The optimiser: the batched interior point with exact autodiff derivatives (split by segment or
coloured by the problem's sparsity), and the nonlinear program it takes."""
