"""Programs compiled quickly where their compile time dominates their run.

A skeleton's registration compiles a dozen programs (the rest spines' tables, the search's
samples, the projection's phases) that each run once, on a few thousand points, in
milliseconds: XLA's optimising compile of them was 13 of the 16 s of spot's first
`register_skeleton`. Compiled with XLA's cheap options instead (no backend optimisation, no
expensive LLVM passes, XLA CPU's older loop emitters, machine code in one piece), they compile
about 3× faster and run a little slower, which on such sizes nobody sees. Large batches
(`fj.register` of a million points) and the per-frame programs keep the optimised compile.

JAX takes compiler options only for a program called at the top level: called inside a
caller's program (a fit, a user's `jit`), the function is compiled with that program, as any
nested function.
"""

from __future__ import annotations

import equinox as eqx

from .._exported import persistent

QUICK_COMPILE = {
    "xla_backend_optimization_level": 0,
    "xla_llvm_disable_expensive_passes": True,
    "xla_cpu_use_fusion_emitters": False,
    "xla_cpu_parallel_codegen_split_count": 1,
}
# Batches up to this many points are registered by quickly compiled programs: at spot's
# 3k vertices a registration runs in about a millisecond either way.
QUICK_BATCH = 1 << 14


def top_level() -> bool:
    """Whether JAX is tracing nothing now: compiler options may be given."""
    try:
        from jax._src.core import trace_state_clean
    except ImportError:  # (a JAX without it: every program compiled the optimised way)
        return False
    return trace_state_clean()


def compiling() -> bool:
    """Whether JAX is tracing a program to compile (`jit`, directly or under other
    transformations), rather than nothing or only transformations applied eagerly (`vmap`,
    `jacfwd`, `grad` of eager code, whose operations would each run, and compile, on their
    own)."""
    try:
        from jax._src.core import trace_ctx
        from jax._src.interpreters.partial_eval import DynamicJaxprTrace
    except ImportError:  # (a JAX without them: taken as compiling, the caller's safe case)
        return True
    trace = trace_ctx.trace
    while trace is not None:  # from the innermost transformation outwards
        if isinstance(trace, DynamicJaxprTrace):
            return True
        trace = getattr(trace, "parent_trace", None)
    return False


class Program:
    """`fun` under `eqx.filter_jit`, compiled either the optimised way or quickly
    (`QUICK_COMPILE`): `program(*args, quick=True)` picks the quick one when called at the
    top level. `kept=True`: its traced program is also kept on disk beside JAX's compilation
    cache (`_exported.persistent`), so that a new process neither traces nor lowers it (for
    programs whose trace reads no constant a test patches)."""

    def __init__(self, fun, kept: bool = False):
        jit = persistent if kept else eqx.filter_jit
        self.optimised = jit(fun)
        self.quick = jit(fun, compiler_options=QUICK_COMPILE)

    def __call__(self, *args, quick: bool = True):
        return self._pick(quick)(*args)

    def prepare(self, *args, quick: bool = True):
        """For a kept program: starts compiling it for a later call on `args` (arrays or
        `jax.ShapeDtypeStruct`s), in a thread (`_exported.persistent`), and returns the call's
        output as `jax.ShapeDtypeStruct`s; `None` where nothing was started (not kept, or no
        cache folder: the call compiles it)."""
        prepare = getattr(self._pick(quick), "prepare", None)
        return None if prepare is None else prepare(*args)

    def _pick(self, quick: bool):
        return self.quick if quick and top_level() else self.optimised
