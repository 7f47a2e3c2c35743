"""Estimation: the compiled joint fit (problem, solver, pipeline), its options and results, model selection."""
