"""The bridge between the two papers: Fleshing's spines found on the medial axis.

Imports `_spines`, `_fleshing` and `_medial_axis`. `rest_spine` (a Fleshing rest spine along
the medial graph's longest path); `skeleton` (`build`: a shape's tree of limbs, `Skeleton` and
`Limb` in `skeleton`, found by `limbs` on the medial graph, their surface parts by `regions`,
saved by `files`); `fit` (the smooth, exactly arc-length spine through a path of spheres, which
both share).
"""
