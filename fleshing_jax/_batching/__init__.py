"""Batching helpers: running per-point functions over a batch in chunks, and compacting the
few points that need a second, costlier pass.

Imports nothing from the package.
"""
