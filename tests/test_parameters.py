"""The parameter registry: lookup by name and group, flags, concatenation, words."""

import numpy as np
import pytest

from pkmcal.machines import default_hexaslide
from pkmcal.parameters import ParameterSet


@pytest.fixture
def hexa():
    return default_hexaslide().parameters


@pytest.fixture
def small():
    return ParameterSet(["a.x", "a.y", "b", "c.angle"], ["length", "length", "ratio", "angle"],
                        [1.0, 2.0, 3.0, 0.5])


def test_index_by_full_name(hexa):
    assert len(hexa) == 54
    for i, name in enumerate(hexa.names):
        assert hexa.index(name) == i
    assert hexa.names[hexa.index("chain3.alpha")] == "chain3.alpha"
    assert hexa.index("chain1.b.x") == 0


def test_indices_by_group_prefix(hexa):
    idx = hexa.indices("chain2.b")
    assert [hexa.names[i] for i in idx] == ["chain2.b.x", "chain2.b.y", "chain2.b.z"]
    chain = hexa.indices("chain4")
    assert len(chain) == 9
    assert all(hexa.names[i].startswith("chain4.") for i in chain)
    # a full name is one position, a list concatenates in the given order
    np.testing.assert_array_equal(hexa.indices("chain1.l"), [hexa.index("chain1.l")])
    np.testing.assert_array_equal(hexa.indices(["chain2.l", "chain1.l"]),
                                  [hexa.index("chain2.l"), hexa.index("chain1.l")])
    assert hexa.indices([]).size == 0


def test_prefix_matches_whole_name_components(hexa):
    """'chain1' is chain 1 only, not chain1x...; 'chain1.b' is not 'chain1.beta'."""
    assert all(hexa.names[i].startswith("chain1.") for i in hexa.indices("chain1"))
    assert "chain1.beta" not in [hexa.names[i] for i in hexa.indices("chain1.b")]


@pytest.mark.parametrize("name", ["chain7.l", "chain1.q", "chain1.b.w", "nothing"])
def test_unknown_names_raise_keyerror_naming_them(hexa, name):
    with pytest.raises(KeyError, match=name.replace(".", r"\.")):
        hexa.indices(name)
    with pytest.raises(KeyError, match=name.replace(".", r"\.")):
        hexa.index(name)
    with pytest.raises(KeyError, match=name.replace(".", r"\.")):
        hexa.with_fixed(name)


def test_group_is_not_a_single_index(hexa):
    with pytest.raises(KeyError, match="chain1.b"):
        hexa.index("chain1.b")          # a group: use indices()


def test_get_values(small, hexa):
    assert small.get("b") == 3.0
    assert isinstance(small.get("b"), float)
    np.testing.assert_array_equal(small.get("a"), [1.0, 2.0])
    np.testing.assert_allclose(hexa.get("chain1.l"), 0.45)
    np.testing.assert_allclose(hexa.get("chain1.b"), [0.12 * np.cos(np.deg2rad(-45)),
                                                      0.12 * np.sin(np.deg2rad(-45)), 0.0])


def test_with_fixed_and_free(hexa):
    fixed = hexa.with_fixed(["chain1.b", "chain2.l"])
    expected = np.zeros(54, bool)
    expected[hexa.indices(["chain1.b", "chain2.l"])] = True
    np.testing.assert_array_equal(fixed.fixed, expected)
    np.testing.assert_array_equal(fixed.free, ~expected)
    assert not hexa.fixed.any(), "with_fixed must not modify the original"
    freed = fixed.with_fixed("chain1.b.y", False)
    expected[hexa.index("chain1.b.y")] = False
    np.testing.assert_array_equal(freed.fixed, expected)
    np.testing.assert_array_equal(freed.values, hexa.values)
    assert freed.names == hexa.names


def test_values_are_read_only(small):
    with pytest.raises(ValueError):
        small.values[0] = 7.0
    with pytest.raises(ValueError):
        small.fixed[0] = True
    new = small.with_values([9.0, 8.0, 7.0, 6.0])
    np.testing.assert_array_equal(new.values, [9.0, 8.0, 7.0, 6.0])
    np.testing.assert_array_equal(small.values, [1.0, 2.0, 3.0, 0.5])


def test_concat(small):
    link = ParameterSet(["link.length"], ["length"], [0.3], fixed=[True])
    both = small.concat(link)
    assert both.names == small.names + ("link.length",)
    assert both.kinds == small.kinds + ("length",)
    np.testing.assert_array_equal(both.values, [1.0, 2.0, 3.0, 0.5, 0.3])
    np.testing.assert_array_equal(both.fixed, [False, False, False, False, True])
    assert both.index("link.length") == 4
    with pytest.raises(ValueError, match="unique"):
        small.concat(small)


def test_scales(small):
    np.testing.assert_array_equal(small.scales(0.45), [0.45, 0.45, 1.0, 1.0])


@pytest.mark.parametrize("kwargs,match", [
    (dict(names=["a", "b"], kinds=["length"], values=[1, 2]), "same length"),
    (dict(names=["a", "a"], kinds=["length"] * 2, values=[1, 2]), "unique"),
    (dict(names=["a"], kinds=["mass"], values=[1]), "mass"),
    (dict(names=["a"], kinds=["length"], values=[1], fixed=[True, False]), "same length"),
])
def test_invalid_sets(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ParameterSet(**kwargs)


# -- words ---------------------------------------------------------------------------------------

def test_describe_direction_difference(hexa):
    d = np.zeros(54)
    d[hexa.index("chain2.b.z")] = 1 / np.sqrt(2)
    d[hexa.index("chain2.a0.z")] = -1 / np.sqrt(2)
    words = hexa.describe_direction(d)
    assert words in ("chain2.b.z - chain2.a0.z", "chain2.a0.z - chain2.b.z")
    # the sign of a direction is arbitrary: both signs give the same words
    assert hexa.describe_direction(-d) == words


def test_describe_direction_coefficients_and_cut(small):
    d = np.array([0.0, 2.0, -1.0, 0.1])         # c.angle below 15 % of the largest: dropped
    assert small.describe_direction(d) == "a.y - 0.5 b"
    assert small.describe_direction(-d) == "a.y - 0.5 b"
    assert small.describe_direction(d, rel=0.01) == "a.y - 0.5 b + 0.05 c.angle"
    assert small.describe_direction(np.array([1.0, 1.0, 1.0, 1.0]), top=2) == "a.x + a.y + ..."
    assert small.describe_direction(np.zeros(4)) == "0"
