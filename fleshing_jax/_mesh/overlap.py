"""The registration and the target's preparation side by side, for cold starts.

A command-line bend compiles a handful of programs before any work, each by XLA in one thread:
the source's preparation and the registration, then the target's preparation (the largest:
tables, frames and reach bounds) and the pose. The target's preparation depends on nothing the
registration computes, so it runs in a second thread while the registration compiles and runs,
and on a 2-core machine the two compilations overlap.

JAX's configuration can be overridden per thread (`with jax.enable_x64(...)`), and such an
override does not reach another thread: the preparation then runs in the caller's thread, after
the registration, with the same result.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import jax

from .._fleshing.ends import end_frames
from .._fleshing.pipeline import Poser, prepare_target, register
from .._fleshing.projection import Registration
from .._numerics import cast_floats
from .._spines.spine import AbstractSpine


def _configuration() -> tuple:
    """What a thread's JAX configuration decides about the preparation: precision, device."""
    return jax.config.jax_enable_x64, jax.config.jax_default_device


def register_and_prepare(
    points: jax.Array, source: AbstractSpine, target: AbstractSpine, **options
) -> tuple[Registration, Poser]:
    """`(register(points, source), prepare_target(target, points.dtype, **options))`, the
    second in a thread of its own when that thread sees the caller's configuration."""
    caller = _configuration()
    # The source's end frames, from which the target's first normal is carried (`ends`).
    options = dict(options, start=end_frames(cast_floats(source, points.dtype)._prepare()))

    def prepare() -> Poser | None:
        if _configuration() != caller:
            return None
        return prepare_target(target, points.dtype, **options)

    with ThreadPoolExecutor(max_workers=1) as pool:
        prepared = pool.submit(prepare)
        registration = register(points, source, margin=options.get("margin", 0.0))
        poser = prepared.result()  # (an error in the thread is raised here)
    if poser is None:
        poser = prepare_target(target, points.dtype, **options)
    return registration, poser
