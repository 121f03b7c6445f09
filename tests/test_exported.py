"""`_exported.persistent`: traced programs kept on disk, so that a first call in a new process
does not trace. A new process is simulated by emptying the in-memory table of loaded programs;
the folder is a temporary one (JAX's configuration is left as it is)."""

from collections import OrderedDict

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fleshing_jax import _exported

traces = []  # one entry per trace of `scaled`'s Python body


class Scale(eqx.Module):
    factor: jax.Array
    power: int = eqx.field(static=True)


def _scaled(scale, x, shift, mode):
    traces.append(mode)
    y = scale.factor * x**scale.power + shift
    return (jnp.sum(y) if mode == "sum" else jnp.max(y)), y * 2


scaled = _exported.persistent(_scaled)


@pytest.fixture
def folder(tmp_path, monkeypatch):
    monkeypatch.setattr(_exported, "_folder", lambda: tmp_path)
    monkeypatch.setattr(_exported, "_loaded", OrderedDict())
    traces.clear()
    return tmp_path


def _new_process(monkeypatch):
    monkeypatch.setattr(_exported, "_loaded", OrderedDict())


def test_a_warm_call_loads_the_program_without_tracing(folder, monkeypatch):
    scale, x = Scale(jnp.asarray(1.5), 2), np.linspace(0.0, 1.0, 5)
    expected = eqx.filter_jit(_scaled)(scale, x, 0.5, "sum")
    traces.clear()
    first = scaled(scale, x, 0.5, "sum")
    assert traces == ["sum"] and len(list(folder.iterdir())) == 1
    _new_process(monkeypatch)
    again = scaled(scale, jnp.asarray(x), 0.5, "sum")
    assert traces == ["sum"]  # loaded, not traced
    for a, b, c in zip(first, again, expected):
        np.testing.assert_array_equal(a, c)
        np.testing.assert_array_equal(b, c)
    # Each thing that decides the trace has its own program: a static argument, a static
    # field, a shape, a dtype.
    scaled(scale, x, 0.5, "max")
    scaled(Scale(jnp.asarray(1.5), 3), x, 0.5, "sum")
    scaled(scale, x[:4], 0.5, "sum")
    scaled(scale, x.astype(np.float32), 0.5, "sum")
    assert len(traces) == 5 and len(list(folder.iterdir())) == 5
    _new_process(monkeypatch)
    out = scaled(Scale(jnp.asarray(2.0), 3), x, 0.5, "sum")  # another value: the same program
    assert len(traces) == 5
    np.testing.assert_allclose(out[1], 2 * (2.0 * x**3 + 0.5), rtol=1e-15)


def test_traced_calls_compile_as_filter_jit(folder):
    scale, x = Scale(jnp.asarray(1.5), 2), jnp.linspace(0.0, 1.0, 5)
    gradient = jax.grad(lambda f: scaled(Scale(f, 2), x, 0.5, "sum")[0])(1.5)
    np.testing.assert_allclose(gradient, jnp.sum(x**2), rtol=1e-15)
    jitted = jax.jit(lambda x: scaled(scale, x, 0.5, "sum"))(x)
    np.testing.assert_allclose(jitted[0], jnp.sum(1.5 * x**2 + 0.5), rtol=1e-15)
    assert list(folder.iterdir()) == []


def test_a_damaged_program_is_exported_again(folder, monkeypatch):
    scale, x = Scale(jnp.asarray(1.5), 2), np.linspace(0.0, 1.0, 5)
    expected = scaled(scale, x, 0.5, "sum")
    (path,) = folder.iterdir()
    path.write_bytes(b"not a program")
    _new_process(monkeypatch)
    out = scaled(scale, x, 0.5, "sum")
    assert len(traces) == 2
    np.testing.assert_array_equal(out[1], expected[1])
    _new_process(monkeypatch)
    scaled(scale, x, 0.5, "sum")
    assert len(traces) == 2  # the file was written again


def _scaled_module(scale, x):
    traces.append("module")
    return Scale(scale.factor * x, scale.power + 1), "kept as it is"


scaled_module = _exported.persistent(_scaled_module, compiler_options={
    "xla_backend_optimization_level": 0})


def test_an_output_of_modules_is_rebuilt_from_its_outline(folder, monkeypatch):
    # An equinox module with a static field (and a static Python value) comes back whole from
    # a loaded program, compiled with the compiler options given.
    scale, x = Scale(jnp.asarray(1.5), 2), np.linspace(0.0, 1.0, 5)
    first, text = scaled_module(scale, x)
    _new_process(monkeypatch)
    again, text_again = scaled_module(scale, x)
    assert traces == ["module"] and len(list(folder.iterdir())) == 1
    assert isinstance(again, Scale) and again.power == 3 and text_again == text == "kept as it is"
    np.testing.assert_array_equal(again.factor, 1.5 * x)
    np.testing.assert_array_equal(first.factor, again.factor)
    # Committed to a device as `jit` leaves its outputs (a loaded program's are committed:
    # mixed with `jit`'s in eager operations, each compiled once more).
    jitted = eqx.filter_jit(_scaled_module)(scale, jnp.asarray(x))[0]
    assert again.factor.committed == jitted.factor.committed


class Named(eqx.Module):
    factor: jax.Array
    how: object = eqx.field(static=True)


def test_a_static_value_printed_by_its_address_is_not_kept(folder):
    # A static field whose printed form differs from process to process (an object at its
    # address) cannot key a file: the call is jitted as without a folder, nothing written.
    traced = _exported.persistent(lambda named: named.factor * 2)
    np.testing.assert_array_equal(traced(Named(jnp.asarray(3.0), object())), 6.0)
    assert list(folder.iterdir()) == []


def _norm(x):
    return jnp.max(jnp.abs(x))


class Normed(eqx.Module):
    factor: jax.Array
    norm: object  # (a field, not static: a leaf that is not an array, as a solver's `norm`)


def test_a_function_among_the_static_values_keys_a_program_by_its_name(folder):
    # A module's function among the values not traced (a solver's `norm`) prints by its
    # address, but is the same in every process: keyed by its module and name, kept.
    traced = _exported.persistent(lambda normed: normed.norm(normed.factor))
    np.testing.assert_array_equal(traced(Normed(jnp.asarray(-3.0), _norm)), 3.0)
    assert len(list(folder.iterdir())) == 1


def test_a_registration_s_skeleton_key_is_the_same_in_every_process():
    # Its static `skeleton_id` is in the key of the programs kept on disk: digests, not
    # Python's `hash` of bytes, which is salted per process.
    from fleshing_jax._skeleton.posing import _digest

    assert _digest(b"spot") == _digest(b"spot") == -1178126572939867824
    assert _digest(b"sp", b"ot") != _digest(b"spot")


def test_a_free_form_spine_s_static_fields_print_the_same_in_every_process():
    # A prepared spine's evaluators (static) print by their functions' names: the key of the
    # skeleton's registration programs kept on disk (`_skeleton.posing`), not their addresses.
    import fleshing_jax as fj

    control = np.array([[0.0, 0, 0], [1, 0, 0], [2, 1, 0], [3, 1, 1], [4, 0, 1], [5, 0, 0]])
    for spine in (fj.BSpline(control), fj.Polyline(control), fj.InterpolatingPolynomial(control)):
        static = eqx.partition(spine._prepare(), eqx.is_array)[1]
        printed = repr(jax.tree.structure(static))
        assert " at 0x" not in printed and "Evaluators(length=fleshing_jax." in printed, printed


def _doubled_on_the_host(x):
    traces.append("callback")
    return jax.pure_callback(lambda a: np.asarray(a) * 2, jax.ShapeDtypeStruct(x.shape, x.dtype),
                             x) + 1


doubled_on_the_host = _exported.persistent(_doubled_on_the_host)


def test_a_program_jax_cannot_export_is_jitted(folder):
    # A host callback cannot be exported: jitted as without a folder, tried once (not traced
    # again on the next call), nothing written.
    x = np.arange(3.0)
    np.testing.assert_array_equal(doubled_on_the_host(x), 2 * x + 1)
    np.testing.assert_array_equal(doubled_on_the_host(x), 2 * x + 1)
    assert traces == ["callback", "callback"]  # the export's trace, then jit's (once)
    assert list(folder.iterdir()) == []


def test_prepare_compiles_ahead_from_shapes(folder, monkeypatch):
    # `prepare` traces once (from shapes, or arrays), compiles in a thread, and returns the
    # output's shapes: the call then neither traces nor compiles again (a skeleton's
    # registration chains its programs so). Without a folder: `None`, nothing started.
    from jax._src import compiler

    scale, x = Scale(jnp.asarray(1.5, jnp.float64), 2), np.linspace(0.0, 1.0, 5)
    shapes = scaled_module.prepare(Scale(jax.ShapeDtypeStruct((), jnp.float64), 2),
                                   jax.ShapeDtypeStruct((5,), jnp.float64))
    assert traces == ["module"] and isinstance(shapes[0], Scale) and shapes[0].power == 3
    assert shapes[0].factor.shape == (5,) and shapes[0].factor.dtype == jnp.float64
    for loaded in _exported._loaded.values():
        # (Not a daemon: a process ending while it compiles waits, not aborts.)
        assert not loaded.compiling.daemon
        loaded.compiling.join()
    compiles = []
    monkeypatch.setattr(compiler, "compile_or_get_cached", lambda *a, **k: compiles.append(a))
    out, _ = scaled_module(scale, x)
    assert traces == ["module"] and compiles == []
    np.testing.assert_array_equal(out.factor, 1.5 * x)
    monkeypatch.setattr(_exported, "_folder", lambda: None)
    assert scaled_module.prepare(scale, x) is None
