"""The parameter table: every name is a real field, defaults lie in range, coordinates and
genotypes round-trip."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from navsvc.errors import ConfigError
from navsvc.session import SessionConfig, apply_profile
from navsvc.tuning.params import (
    BY_NAME,
    DEFAULT_SET,
    TABLE,
    Parameter,
    decode,
    genotype_length,
    genotype_to_unit,
    select,
    unit_to_genotype,
)
from navsvc.tuning.profile import current_value


@pytest.mark.parametrize("p", TABLE, ids=lambda p: p.name)
def test_every_parameter_is_a_field_with_its_default_in_range(p: Parameter) -> None:
    default = current_value(SessionConfig(), p.name)
    if p.choices:
        assert default in p.choices
    else:
        assert p.low <= default <= p.high
        assert p.value(p.unit(default)) == pytest.approx(default, rel=1e-4)
    for u in (0.0, 0.5, 1.0):  # the whole range is accepted by the configuration
        config = apply_profile(SessionConfig(), {p.name: p.value(u)})
        if p.name.endswith(".scale"):  # a fuzzy set scaled: its SMALL set's second corner
            sets = p.name.split(".")[2]
            base = getattr(SessionConfig().fusion.fuzzy, sets)
            key = next(iter(base))
            assert getattr(config.fusion.fuzzy, sets)[key][2] == \
                pytest.approx(base[key][2] * p.value(u))
        else:
            assert current_value(config, p.name) == pytest.approx(p.value(u))


def test_scales() -> None:
    log = Parameter("fusion.gps_uere_m", "x", 1.0, 100.0, "log")
    assert [log.value(u) for u in (0.0, 0.5, 1.0)] == [1.0, 10.0, 100.0]
    lin = Parameter("matcher.prior_keep", "x", 0.0, 0.8)
    assert lin.value(0.25) == 0.2 and lin.value(-1.0) == 0.0 and lin.value(2.0) == 0.8
    assert BY_NAME["fusion.inflate_after_gated_fixes"].value(0.5) == 6  # integer: rounded
    assert BY_NAME["map_feedback"].value(0.4) is False and BY_NAME["map_feedback"].value(0.6)


@given(st.lists(st.integers(0, 1), min_size=genotype_length(select()),
                max_size=genotype_length(select())))
def test_genotypes_round_trip(bits: list[int]) -> None:
    params = select()
    assert unit_to_genotype(params, genotype_to_unit(params, bits)) == bits


def test_genotype_bits_are_gray_code_most_significant_first() -> None:
    params = (Parameter("a", "x", 0.0, 3.0, bits=2), Parameter("b", "x", 0.0, 1.0, bits=1))
    # Gray 11 is binary 10: a = 2; Gray 10 is binary 11: a = 3
    assert decode(params, genotype_to_unit(params, [1, 1, 1])) == {"a": 2.0, "b": 1.0}
    assert decode(params, genotype_to_unit(params, [1, 0, 0])) == {"a": 3.0, "b": 0.0}
    eight = (Parameter("c", "x", 0.0, 255.0, bits=8, integer=True),)
    for k in range(255):  # neighbouring values differ in exactly one bit
        a, b = (unit_to_genotype(eight, [v / 255.0]) for v in (k, k + 1))
        assert sum(x != y for x, y in zip(a, b)) == 1


def test_selection_and_its_errors() -> None:
    assert [p.name for p in select()] == list(DEFAULT_SET)
    assert [p.name for p in select(["matcher.road_sigma_m"])] == ["matcher.road_sigma_m"]
    with pytest.raises(ConfigError, match=r"^unknown parameter\(s\) fusion.nope; known: "):
        select(["fusion.nope"])
    with pytest.raises(ConfigError, match="^a parameter is named twice$"):
        select(["matcher.road_sigma_m", "matcher.road_sigma_m"])
    with pytest.raises(ConfigError, match="^x: a log scale needs low > 0$"):
        Parameter("x", "c", 0.0, 1.0, "log")
