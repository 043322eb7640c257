"""trustnav.schema, the one validation mechanism (issue 37, item 2): rules, their expected forms, the
key meant for a misspelled one, one line per error naming where; every key of a scenario file
and of the paper's presets is checked by a rule."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Annotated

import pytest
from hypothesis import given
from hypothesis import strategies as st

from trustnav.schema import (
    Dotted,
    Either,
    Flag,
    InFile,
    Integer,
    Invalid,
    Maybe,
    Number,
    OneOf,
    Pair,
    SchemaError,
    Seq,
    Text,
    check_fields,
    did_you_mean,
    load,
    rules_of,
)


@given(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(-10, 10),
    st.floats(-10, 10),
    st.booleans(),
    st.booleans(),
)
def test_a_number_rule_takes_exactly_the_numbers_in_its_range(v, a, b, lo_open, hi_open):
    lo, hi = min(a, b), max(a, b)
    rule = Number(lo, hi, lo_open=lo_open, hi_open=hi_open)
    inside = math.isfinite(v) and (v > lo if lo_open else v >= lo) and (v < hi if hi_open else v <= hi)
    if inside:
        assert rule(v) == v
    else:
        with pytest.raises(Invalid) as exc:
            rule(v)
        assert exc.value.expected == rule.expected and exc.value.value is v


@pytest.mark.parametrize(
    ("rule", "expected"),
    [
        (Number(lo=0, lo_open=True), "a number > 0"),
        (Number(0, 1, hi_open=True), "a number in [0, 1)"),
        (Number(0, 20, lo_open=True, unit=" m"), "a number in (0, 20] m"),
        (Number(), "a finite number"),
        (Number(lo=0, finite=False), "a number >= 0"),
        (Integer(1, unit=" steps"), "an integer >= 1 steps"),
        (Integer(1, 100), "an integer in [1, 100]"),
        (Flag(), "true or false"),
        (OneOf("paper", "authors_code"), "one of 'paper', 'authors_code'"),
        (Maybe(Number(1, 170), "the scenario's"), "a number in [1, 170] or left out (the scenario's)"),
        (Pair(), "two finite numbers [x, y]"),
    ],
)
def test_each_rule_says_what_it_expects(rule, expected):
    assert rule.expected == expected


def test_rules_refuse_what_a_file_gets_wrong_and_normalise_what_it_gets_right():
    for rule, bad in [(Number(), "3"), (Number(), True), (Number(), math.nan), (Integer(), 2.5), (Integer(), True),
                      (Flag(), 1), (OneOf(True, False), 1), (Text(), ""), (Pair(), [1]), (Pair(), "xy"),
                      (Pair(), [1, math.inf]), (Seq(Integer(1)), 3), (OneOf("a"), ["a"])]:  # fmt: skip
        with pytest.raises(Invalid):
            rule(bad)
    assert Pair()([1, 2]) == (1.0, 2.0) and isinstance(Pair()([1, 2]), tuple)
    assert Integer(whole_floats=True)(4.0) == 4 and Number(cast=True)(3) == 3.0
    assert Seq(Pair())([[0, 1], [2, 3]]) == ((0.0, 1.0), (2.0, 3.0))
    assert Seq(Number(), kind=list)((1, 2)) == [1, 2]
    assert Either(Text(), Integer(0))(3) == 3 and Maybe(Integer())(None) is None
    with pytest.raises(Invalid) as exc:  # an item of a list is named by its index
        Seq(Integer(1))([1, 0])
    assert exc.value.at == "[1]" and exc.value.value == 0
    with pytest.raises(Invalid):
        Seq(Number(), min_len=2, max_len=2, ascending=True)([2, 1])


def test_the_key_meant_is_named_or_else_the_keys_expected():
    keys = ["horizon", "dt", "safety_radius", "rate"]
    assert did_you_mean("horizn", keys) == "did you mean 'horizon'?"
    assert did_you_mean("saftey_radius", keys) == "did you mean 'safety_radius'?"
    assert did_you_mean("colour", keys) == "expected one of dt, horizon, rate, safety_radius"


@dataclass(frozen=True)
class _Inner:
    gain: Annotated[float, Number(lo=0, lo_open=True)] = 1.0


@dataclass(frozen=True)
class _Section:
    horizon: Annotated[int, Integer(1)]
    dt: Annotated[float, Number(lo=0, lo_open=True, unit=" s")] = 0.1
    start: Annotated[tuple[float, float], Pair()] = (0.0, 0.0)
    flag: bool = False
    label: str | None = None
    inner: _Inner = dataclasses.field(default_factory=_Inner)

    def __post_init__(self) -> None:
        check_fields(self)
        if self.horizon * self.dt > 10:
            raise ValueError("horizon * dt must be at most 10 s")


def test_load_gives_one_line_per_error_naming_file_section_and_key():
    place = InFile("kerb-gap.toml", "[control]")
    with pytest.raises(SchemaError) as exc:
        load(_Section, {"horizn": 5, "dt": "fast", "flag": 1, "label": 3, "inner": {"gain": -1, "gian": 2}}, place)
    assert exc.value.errors == (
        "unknown key 'horizn' in [control] of kerb-gap.toml: did you mean 'horizon'?",
        "dt in [control] of kerb-gap.toml must be a number > 0 s, got 'fast'",
        "flag in [control] of kerb-gap.toml must be true or false, got 1",
        "label in [control] of kerb-gap.toml must be a string or left out, got 3",
        "unknown key 'gian' in [control.inner] of kerb-gap.toml: did you mean 'gain'?",
        "gain in [control.inner] of kerb-gap.toml must be a number > 0, got -1",
        "missing key 'horizon' in [control] of kerb-gap.toml: expected an integer >= 1",
    )
    assert str(exc.value).count("\n") == len(exc.value.errors) - 1
    with pytest.raises(SchemaError, match=r"^\[control\] of kerb-gap.toml: horizon \* dt must be at most 10 s$"):
        load(_Section, {"horizon": 200}, place)  # a check between fields, after the rules
    with pytest.raises(SchemaError, match=r"^\[control\] of kerb-gap.toml must be a table of keys, got 3$"):
        load(_Section, 3, place)
    s = load(_Section, {"horizon": 5, "start": [1, 2], "inner": {"gain": 2}}, place)
    assert s == _Section(5, start=(1.0, 2.0), inner=_Inner(2.0)) and isinstance(s.start, tuple)


def test_check_fields_refuses_a_bad_object_built_in_python():
    with pytest.raises(SchemaError, match=r"^horizon must be an integer >= 1, got 0\ndt must be a number > 0 s"):
        _Section(horizon=0, dt=-1.0)
    s = _Section(1)
    object.__setattr__(s, "flag", "no")  # changed behind the frozen dataclass's back
    with pytest.raises(SchemaError, match=r"^sweeps.si.flag must be true or false, got 'no'$"):
        check_fields(s, Dotted("sweeps.si"))


def test_dotted_places_name_the_path_and_the_file():
    with pytest.raises(SchemaError) as exc:
        load(_Section, {"horizon": 0, "flg": True}, Dotted("sweeps.si", "spec.yaml"))
    assert exc.value.errors == (
        "unknown key 'flg' in sweeps.si in spec.yaml: did you mean 'flag'?",
        "sweeps.si.horizon in spec.yaml must be an integer >= 1, got 0",
    )


# -- every key a user can write is checked by a rule ------------------------------------------------


def _scenario_classes():
    from trustnav.sim.driving.behaviour import BehaviourSpec
    from trustnav.sim.driving.world import (
        CarlaRouteSpec,
        ControlSpec,
        DriveScenario,
        PedestrianSpec,
        RoadSpec,
        SensingSpec,
        VehicleSpec,
    )
    from trustnav.sim.paper import PaperScenario, Pedestrian

    return [RoadSpec, VehicleSpec, ControlSpec, SensingSpec, CarlaRouteSpec, PedestrianSpec, DriveScenario,
            BehaviourSpec, PaperScenario, Pedestrian]  # fmt: skip


#: fields filled by a loader's own converter (the list of [[pedestrian]] tables, a pedestrian's
#: appearance preset or colours, its alternative behaviour) or a nested section's dataclass
CONVERTED = {"pedestrians", "appearance", "alternative"}


@pytest.mark.parametrize("cls", _scenario_classes(), ids=lambda c: c.__name__)
def test_every_scenario_key_has_a_rule_or_is_a_section(cls):
    import typing

    rules = rules_of(cls)
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        nested = any(dataclasses.is_dataclass(t) for t in (hints[f.name], *typing.get_args(hints[f.name])))
        assert f.name in rules or nested or f.name in CONVERTED, f"{cls.__name__}.{f.name} has no rule"


def test_a_misspelled_scenario_key_names_the_key_meant(tmp_path, drive_scenario, paper_scenario):
    path = tmp_path / "kerb-gap.toml"
    path.write_text(
        'name = "kg"\ntitle = "t"\nego_start = [33.5, 129.0]\ngoal = [33.5, 100.0]\n'
        '[control]\nhorizn = 5\n[[pedestrian]]\nname = "a"\nposition = [37.0, 112.0]\n'
    )
    with pytest.raises(SchemaError) as exc:
        drive_scenario(path)
    assert exc.value.errors == (f"unknown key 'horizn' in [control] of {path}: did you mean 'horizon'?",)
    paper = tmp_path / "paper.toml"
    paper.write_text('name = "p"\ntitle = "t"\nego_start = [0, 0]\ngoal = [0, 9]\nsaftey_radius = 2\n'
                     "[[pedestrian]]\nposition = [1, 5]\ntrsut = 0.5\n")  # fmt: skip
    with pytest.raises(SchemaError) as exc:
        paper_scenario(paper)
    assert exc.value.errors == (
        f"unknown key 'saftey_radius' in {paper}: did you mean 'safety_radius'?",
        f"unknown key 'trsut' in pedestrian 1 of {paper}: did you mean 'trust'?",
    )


def test_every_one_typo_misspelling_of_a_scenario_key_names_the_key_meant():
    """A dropped letter or two swapped neighbours in any key of three letters or more (two-letter keys
    such as ``dt`` have too little to go on), in every section of the scenario files."""
    from trustnav.geometry.camera import CameraSpec
    from trustnav.trust import GammaParams

    for cls in [*_scenario_classes(), CameraSpec, GammaParams]:
        keys = [f.name for f in dataclasses.fields(cls)]
        for k in (k for k in keys if len(k) >= 3):
            typos = {k[:i] + k[i + 1 :] for i in range(len(k))}
            typos |= {k[:i] + k[i + 1] + k[i] + k[i + 2 :] for i in range(len(k) - 1)}
            for typo in typos - set(keys):
                assert did_you_mean(typo, keys) == f"did you mean {k!r}?", (cls.__name__, typo)
