"""Fleshing: the closed-form maps (radial, normal, binormal, skinning), closest projection
and registration, local reach bounds, target frames, the pipeline (`flesh`, `register`,
`pose`, `Fleshing`) and the det J check.

Imports the shared helpers, `_batching` and `_spines`.
"""
