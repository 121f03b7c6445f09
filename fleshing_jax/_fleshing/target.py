"""What bending onto a target spine needs of it at an arc length `s₁`, exact or tabulated.

The bend (paper §3.3) places a point at `C₁(s₁) + d₁ₓ I₁ + d₁ᵧ J₁`, where the map's offset `d₁`
depends on the curvature vector `k₁` in the twisted normals `(I₁, J₁)`: 11 numbers per point,
`(C₁, I₁, J₁, (k₁·I₁, k₁·J₁))`. In single precision they are tabulated (`PiecewiseCubic`) with
the twist folded in, so that a pose looks up exactly these 11 values and uses each once: XLA then
fuses every lookup into the kernel that consumes it. (Looking up the spine table's 15 values and
twisting per point was 5× slower: the shared values were materialised, one kernel each.) An
arc's 11 values are sinusoids of `s₁`, given exactly by three coefficients each (`Sinusoid`):
one `sincos` a point instead of 44 table reads, the most expensive part of a pose.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._batching.grid import grid_vmap
from .._numerics import dot, held_trig
from .._spines.frames import twist_normals
from .._spines.sinusoid import Sinusoid
from .._spines.spine import AbstractSpine
from .._spines.table import PiecewiseCubic, SpineTable, tabulated
from .reach import search_range


def target_frame(spine: AbstractSpine, twist: Array, s: Array) -> tuple[Array, ...]:
    """`(C (3,), I (3,), J (3,), k in (I, J) (2,))` of a prepared `spine` at `s`, with its
    normals turned by `twist` radians."""
    return frame_of(*spine.jet_and_normals(s), twist)


def frame_of(jet: tuple[Array, Array, Array], normals: tuple[Array, Array],
             twist: Array, trig: tuple[Array, Array] | None = None) -> tuple[Array, ...]:
    """`target_frame` from the spine's `jet` `(C, T, k)` and `normals` `(I, J)` (each (3,));
    `trig`: `(cos, sin)` of `twist`, where the caller has them."""
    (c, _, k), (i, j) = jet, twist_normals(normals, twist, trig)
    return c, i, j, jnp.stack([dot(k, i), dot(k, j)])


class TargetFrames(eqx.Module):
    """The frames of a target spine, with a twist, as a function of arc length (`__call__`).

    **Arguments:** `spine`: the target (an `AbstractSpine` or its `SpineTable`); `twist`: scalar
    radians; `tabulate`: look the frames up in a table (single precision; for an arc, its
    `Sinusoid`) rather than evaluate `spine` at every point; `at_nodes`: where `spine` is a
    `SpineTable` that a spine made of itself, the values `(jet, normals)` it was fit to at its
    nodes (`table.fast_evaluator_at_nodes`), from which the frames' table is fit on its pieces.

    **Attributes:** `length`; `lo`, `hi`: the target's closest-point search range, where frames
    are defined.
    """

    spine: AbstractSpine | SpineTable  # prepared
    twist: Array
    table: PiecewiseCubic | Sinusoid | None

    def __init__(self, spine: AbstractSpine | SpineTable, twist: Array, tabulate: bool = False,
                 at_nodes: tuple | None = None):
        self.spine, self.twist = spine._prepare(), twist
        self.table = None
        if tabulate and at_nodes is not None:
            # The frames at the table's nodes from the values it was fit to there: read back
            # from its cubics (coefficients times the nodes' powers), XLA fused the values'
            # making (a bent limb's rotations) into every read of them, a tenth of a float32
            # frame of spot's leg. (The twist's sine and cosine held: `held_trig`.)
            trig = held_trig(twist)[0]

            def frame(jet, normals):
                return jnp.concatenate(frame_of(jet, normals, twist, trig))

            frames = grid_vmap(frame, *at_nodes)
            self.table = self.spine.cubics.refit(frames)
        elif tabulate:
            prepared = self.spine  # (not `self` in a lambda: the module is not frozen yet)
            self.table = tabulated(
                prepared, lambda s: jnp.concatenate(target_frame(prepared, twist, s))
            )

    @property
    def length(self) -> Array:
        return self.spine.length

    @property
    def lo(self) -> Array:
        return search_range(self.spine)[0]

    @property
    def hi(self) -> Array:
        return search_range(self.spine)[1]

    def __call__(self, s: Array) -> tuple[Array, ...]:
        """`(C₁ (3,), I₁ (3,), J₁ (3,), k₁ in (I₁, J₁) (2,))` at `s` (one point)."""
        if self.table is None:
            return target_frame(self.spine, self.twist, s)
        v = self.table.fields(s)
        return jnp.stack(v[0:3]), jnp.stack(v[3:6]), jnp.stack(v[6:9]), jnp.stack(v[9:11])

    def coordinates(self, s: Array) -> tuple[list[Array], list[Array], list[Array]]:
        """`(C₁, I₁, J₁)` at arc lengths `s` (n,), each as its three coordinates (each (n,)):
        looked up in the table, one value at a time (tabulated frames only)."""
        v = jax.vmap(lambda one: self.table.fields(one)[0:9])(s)
        return v[0:3], v[3:6], v[6:9]
