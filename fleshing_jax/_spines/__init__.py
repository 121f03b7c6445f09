"""Spines: the spine interface and its continuation past the ends, the analytic spines
(line, arc, helix), the piecewise-polynomial base with exact arc length, B-splines, the
interpolating polynomial, polylines, frames (Frenet, rotation-minimising, double
reflection), the float32 tables of cubic pieces, and spine JSON files.

Imports only the shared helpers (`_numerics`, `_checks`).
"""
