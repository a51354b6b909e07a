"""Every preset, cycle, method, driver, mode and energy management gives the fuel kept in
``tests/fuel_reference.json`` (``tests/fuel_reference.py`` says how it is written and why each tolerance is
what the method can do): a change meant to leave the model alone is held to it by every test run."""

from __future__ import annotations

import json
from collections import defaultdict

import pytest

from fuel_reference import REFERENCE, cases, figure

CASES = list(cases())
BY_PRESET = defaultdict(list)
for case in CASES:
    BY_PRESET[case[1]].append(case)


@pytest.fixture(scope="module")
def reference() -> dict:
    return json.loads(REFERENCE.read_text())["cases"]


def test_the_reference_holds_every_case_and_no_other(reference):
    assert set(reference) == {key for key, *_ in CASES}


@pytest.mark.parametrize("preset", sorted(BY_PRESET))
def test_the_fuel_is_the_references(preset, reference):
    moved = []
    for key, p, cycle, method, kw, tol in BY_PRESET[preset]:
        want = reference[key]
        got = figure(p, cycle, method, kw)
        rel = abs(got - want) / abs(want) if want else abs(got)
        if not rel <= tol:
            moved.append(f"{key}: {got!r} against {want!r} ({rel:.2e} > {tol:g})")
    assert not moved, (
        f"{len(moved)} case(s) moved; if on purpose, rewrite the reference (python tests/fuel_reference.py) "
        "and say why in the commit:\n" + "\n".join(moved)
    )
