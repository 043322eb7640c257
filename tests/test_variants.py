"""The drive command's orchestration in the library (issue 37): a case's variants, the scenario with
command-line options applied, every variant driven through the caller's world."""

from __future__ import annotations

import contextlib
import dataclasses

import pytest

from trustnav.sim.driving import load_drive_scenario
from trustnav.sim.driving.variants import drive_variants, variants_of


def test_variants_of_a_case():
    one, two = load_drive_scenario("case-1"), load_drive_scenario("case-2")
    assert variants_of(one) == [("", None)]
    assert variants_of(two) == [(v, v == "attentive") for v in two.variants] and len(two.variants) == 2
    assert variants_of(two, attentive=False) == [("distracted", False)]
    assert variants_of(one, attentive=True) == [("attentive", True)]


def test_drive_variants_drives_each_variant_in_its_own_progress_context():
    sc = load_drive_scenario("case-2")
    seen, opened = [], []

    @contextlib.contextmanager
    def reporter(tag):  # type: ignore[no-untyped-def]
        opened.append(tag)
        yield lambda t, d: None

    runs = drive_variants(sc, None, lambda s, att, progress: seen.append((s, att, progress)) or att, reporter)
    assert [tag for tag, _ in runs] == list(sc.variants) == opened
    assert [r for _, r in runs] == [v == "attentive" for v in sc.variants]
    assert all(s is sc and callable(p) for s, _, p in seen)


def test_with_options_replaces_the_given_fields_and_validates_them():
    sc = load_drive_scenario("case-1")
    assert sc.with_options(camera={"fov_deg": None}) is sc  # nothing given: the scenario as it is
    new = sc.with_options(5.0, camera={"fov_deg": 80.0}, control={"horizon": 7, "safety_radius": None})
    assert new.duration == 5.0 and new.camera.fov_deg == 80.0 and new.control.horizon == 7
    assert new.control.safety_radius == sc.control.safety_radius
    assert dataclasses.replace(new, duration=sc.duration, camera=sc.camera, control=sc.control) == sc
    with pytest.raises(ValueError, match="horizon"):
        sc.with_options(control={"horizon": 0})
