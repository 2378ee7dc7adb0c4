"""Numba kernels of the filter: UD factorization, rotations, models and Jacobians, propagation, updates, time update."""
