"""The optimal walking step: the problem, its solver, reports, heuristic starts, the MuJoCo C reference."""
