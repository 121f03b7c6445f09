"""Fitting spines: the shared set-up of a fitting problem (parameters, regularisers, solvers,
results), fitting with correspondences, and Chamfer fitting to point clouds.

Imports the shared helpers, `_spines` and `_fleshing`.
"""
