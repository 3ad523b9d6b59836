"""Hypothesis pieces for fuzzing our JSON readers: any JSON value, put in place of (or instead of) any
part of a valid document."""

from hypothesis import strategies as st

#: A JSON value of any kind, to replace a part of a valid file.
JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**80), 2**80) | st.floats() | st.text(max_size=5),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=12,
)


def _paths(value, prefix=()):
    yield prefix
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from _paths(v, (*prefix, i))


def mutate(document, data, how: str) -> None:
    """Replace (``how="replace"``) or delete (``"delete"``) one part of ``document`` in place, drawn
    with hypothesis's ``data``."""
    path = data.draw(st.sampled_from([p for p in _paths(document) if p]))
    parent = document
    for key in path[:-1]:
        parent = parent[key]
    if how == "replace":
        parent[path[-1]] = data.draw(JSON_VALUES)
    else:
        del parent[path[-1]]
