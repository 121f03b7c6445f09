"""A solver's step budget as a value (`_fit.budget`): the same steps as optimistix's static
`max_steps`, and one compiled solve for every budget."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

from fleshing_jax._fit.budget import budgeted


def rosenbrock(y, args=None):
    """Residuals whose least-squares minimum at (1, 1) takes Levenberg–Marquardt and BFGS
    a dozen steps or more from (-1.2, 1)."""
    return jnp.stack([10 * (y[1] - y[0] ** 2), 1 - y[0]])


Y0 = jnp.array([-1.2, 1.0])
TRACES = []


@eqx.filter_jit
def solve(solver, max_steps):
    TRACES.append(None)  # once per compilation
    solution = optx.least_squares(rosenbrock, solver, Y0, max_steps=max_steps, throw=False)
    return solution.value, solution.result, solution.stats["num_steps"]


@pytest.mark.parametrize(
    "solver",
    [optx.LevenbergMarquardt(1e-10, 1e-10), optx.BFGS(1e-10, 1e-10)],
    ids=["least-squares", "minimiser"],
)
def test_a_budget_takes_the_static_limit_s_steps_in_one_program(solver):
    free, result, steps = solve(solver, 64)
    assert result == optx.RESULTS.successful and 5 < int(steps) < 64
    np.testing.assert_allclose(np.asarray(free), [1.0, 1.0], atol=1e-6)
    TRACES.clear()
    for budget in (2, 4):
        y, result, steps = solve(budgeted(solver, budget), 64)
        expected, expected_result, _ = solve(solver, budget)  # optimistix's own limit
        np.testing.assert_array_equal(np.asarray(y), np.asarray(expected))
        assert int(steps) == budget
        assert result == expected_result == optx.RESULTS.nonlinear_max_steps_reached
    # Two budgets, one program (and the two static limits' own).
    assert len(TRACES) == 3
    # A budget the solve does not reach leaves it as it was.
    y, result, steps = solve(budgeted(solver, 64), 64)
    np.testing.assert_array_equal(np.asarray(y), np.asarray(free))
    assert result == optx.RESULTS.successful and len(TRACES) == 3


def test_a_budget_needs_an_optimistix_solver():
    with pytest.raises(TypeError, match="`solver`"):
        budgeted(object(), 3)
