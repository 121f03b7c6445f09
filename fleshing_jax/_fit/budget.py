"""A solver's step budget as a value, so that solves with different budgets share one program.

`optimistix.least_squares`'s `max_steps` is static: each value compiles its own solve. A fit
in stages (the shape fit's continuation: short stages that only bring the pose near, then a
long last one) would compile its solve once per budget, the largest part of its first call.
`budgeted(solver, steps)` wraps `solver` so that it stops itself after `steps` steps (an
array: traced, not static), reporting `nonlinear_max_steps_reached` as optimistix does at its
own limit; every stage then passes the same static `max_steps` (the largest budget) and the
stages run one compiled program. The steps taken are exactly the inner solver's.

A fit's own `max_steps` is such a budget too (`limited`), under one static limit for every
budget up to `STEPS`: a fit cut short (`max_steps=3`) runs the program of the default one.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Int


class _Budget(eqx.Module):
    """The wrapper's behaviour, for a least-squares solver and a minimiser alike: the inner
    solver's state paired with the count of steps taken."""

    solver: eqx.AbstractVar[optx.AbstractLeastSquaresSolver | optx.AbstractMinimiser]
    budget: eqx.AbstractVar[Int[Array, ""]]

    @property
    def rtol(self):
        return self.solver.rtol

    @property
    def atol(self):
        return self.solver.atol

    @property
    def norm(self):
        return self.solver.norm

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        state = self.solver.init(fn, y, args, options, f_struct, aux_struct, tags)
        return state, jnp.zeros((), jnp.int32)

    def step(self, fn, y, args, options, state, tags):
        inner, taken = state
        y, inner, aux = self.solver.step(fn, y, args, options, inner, tags)
        return y, (inner, taken + 1), aux

    def terminate(self, fn, y, args, options, state, tags):
        inner, taken = state
        done, result = self.solver.terminate(fn, y, args, options, inner, tags)
        spent = jnp.invert(done) & (taken >= self.budget)
        result = optx.RESULTS.where(spent, optx.RESULTS.nonlinear_max_steps_reached, result)
        return done | spent, result

    def postprocess(self, fn, y, aux, args, options, state, tags, result):
        return self.solver.postprocess(fn, y, aux, args, options, state[0], tags, result)


class _BudgetedLeastSquares(_Budget, optx.AbstractLeastSquaresSolver):
    solver: optx.AbstractLeastSquaresSolver
    budget: Int[Array, ""]


class _BudgetedMinimiser(_Budget, optx.AbstractMinimiser):
    solver: optx.AbstractMinimiser
    budget: Int[Array, ""]


# The static `max_steps` of every solve whose budget is at most this (the fits' default).
STEPS = 256


def budgeted(solver, steps: int):
    """`solver` (an optimistix least-squares solver or minimiser) stopping after `steps`
    steps, `steps` held as an array (see the module docstring)."""
    budget = jnp.asarray(steps, jnp.int32)
    if isinstance(solver, optx.AbstractLeastSquaresSolver):
        return _BudgetedLeastSquares(solver, budget)
    if isinstance(solver, optx.AbstractMinimiser):
        return _BudgetedMinimiser(solver, budget)
    raise TypeError(f"`solver` must be an optimistix least-squares solver or minimiser, got "
                    f"{type(solver).__name__}.")


def limited(solver, max_steps: int, steps: int | None = None) -> tuple:
    """`(solver, static max_steps)` for `optimistix.least_squares`: `solver` stopping after
    `steps` (default `max_steps`) steps (`budgeted`), under the static limit `STEPS` (or
    `max_steps`, if more), so that every budget up to it shares one compiled solve."""
    return budgeted(solver, max_steps if steps is None else steps), max(int(max_steps), STEPS)


def unbudgeted(solver, state) -> tuple:
    """`(solver, state)` of the solver inside a `budgeted` one (its state paired with the
    steps taken), or as they are."""
    if isinstance(solver, _Budget):
        return solver.solver, state[0]
    return solver, state
