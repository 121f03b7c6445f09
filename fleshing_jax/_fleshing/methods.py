"""The names of the fleshing methods, importable without JAX (the command line's parser)."""

METHODS = ("radial", "normal", "binormal", "skinning")


def check_method(method: str) -> str:
    """Raises `ValueError` unless `method` is one of `METHODS`."""
    if method not in METHODS:
        raise ValueError(f"`method` must be one of {METHODS}, got {method!r}.")
    return method
