"""Meshes: bending meshes and point clouds in chunks, reading and atomic writing, closing
holes, signed volumes, procedural test shapes.

Imports the shared helpers, `_spines` and `_fleshing`.
"""
