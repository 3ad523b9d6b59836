"""One reader for our JSON files (geodesics.schema.Fields): the values JSON lets through that used to
load wrongly, and a fuzz of every reader with mutated files."""

import contextlib
import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from geodesics import ContactError, ContactPatch, ContactSet, farthest_pair_axis
from geodesics.primitives import grid_plane
from geodesics.schema import Fields, is_integer, is_number

from .json_mutations import mutate


@pytest.fixture(scope="module")
def plane():
    return grid_plane(12, 12, size=(1.0, 1.0), seed=3)


@pytest.fixture(scope="module")
def contacts(plane):
    rng = np.random.default_rng(5)
    from geodesics import SurfacePoints

    def patch(faces):
        bary = rng.dirichlet(np.ones(3), size=len(faces))
        points = SurfacePoints(np.asarray(faces), bary)
        return ContactPatch(plane, points, farthest_pair_axis(plane, points))

    s = ContactSet(plane).add("palm", patch(np.arange(40, 70))).add("tip", patch(np.arange(100, 120)))
    return s.parent("tip", "palm").pair("palm", "cup")


def test_json_numbers_are_told_apart():
    assert is_integer(3) and not is_integer(True) and not is_integer(3.0) and not is_integer(2**70)
    assert is_number(1.5) and is_number(2) and not is_number(False) and not is_number(float("nan"))
    assert not is_number(10**400)  # beyond float range


@pytest.mark.parametrize(
    ("change", "message"),
    [
        # Each of these loaded before, as something else: a link of length 1, a version-1 file,
        # barycentrics of 1 and 0, an overflowing face.
        (
            lambda d: d["patches"][1]["link"].update(length=True),
            r"patch 'tip'\.link\.length must be a number",
        ),
        (lambda d: d.update(version=1.0), "version 1.0 is not supported"),
        (
            lambda d: d["patches"][0]["points"].update(bary=[[True, False, False]] * 30),
            r"patch 'palm'\.points\.bary must be an array of n x 3 numbers",
        ),
        (lambda d: d["patches"][0].update(binding=[2**70] * 30), "binding must be a list of integer indices"),
        (lambda d: d["patches"][0].update(pair=7), r"patch 'palm'\.pair must be a string, got 7"),
        (lambda d: d["patches"][0]["axis"].update(lengths="long"), r"axis\.lengths must be a list"),
        (lambda d: d.update(patches=[3]), r"patches\[0\] must be an object, not a number"),
        (lambda d: d.update(mesh=None), "mesh must be an object, got null"),
    ],
)
def test_values_json_lets_through_are_refused(contacts, plane, change, message):
    data = contacts.to_dict()
    change(data)
    with pytest.raises(ContactError, match=message):
        ContactSet.from_dict(json.loads(json.dumps(data)), plane, source="c.json")


def test_a_valid_file_reads_back_exactly(contacts, plane):
    back = ContactSet.from_dict(json.loads(json.dumps(contacts.to_dict())), plane)
    assert back.to_dict() == contacts.to_dict()


def test_fields_name_the_path():
    f = Fields({"a": {"b": [1, 2.5]}}, "x.json", ValueError)
    with pytest.raises(ValueError, match=r"^x\.json: a\.b must be a list of integer indices$"):
        f.object("a").indices("b")
    with pytest.raises(ValueError, match=r"^x\.json: c is missing$"):
        f.string("c")
    assert f.string("c", optional=True) is None
    np.testing.assert_array_equal(f.object("a").numbers("b", (2,)), [1.0, 2.5])


# ----------------------------------------------------------------------------------------- fuzz


@settings(
    derandomize=True,
    max_examples=300,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(data=st.data())
def test_a_mutated_contact_file_loads_or_raises_contact_error(contacts, plane, data):
    """Any one value of a valid file replaced by any JSON value, or deleted: the set loads (the value was
    as good) or ContactError says why; nothing else escapes."""
    document = contacts.to_dict()
    mutate(document, data, data.draw(st.sampled_from(["replace", "delete"])))
    with contextlib.suppress(ContactError):
        ContactSet.from_dict(document, plane, remap=data.draw(st.booleans()))
