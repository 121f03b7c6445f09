"""The bridge between the two papers: Fleshing's spines found on the medial axis.

Imports `_spines`, `_fleshing` and `_medial_axis`. `rest_spine` (a Fleshing rest spine along
the medial graph's longest path).
"""
