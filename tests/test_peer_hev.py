"""The hybrid peer (vpsim.fleet.peer_hev): FASTSim's hybrid with a technology put in, and its calibration's
fit, against synthetic grids with a known answer and against FASTSim's own response."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vpsim.fleet import peer_hev as ph
from vpsim.units import mpg_from_l_per_100km


def test_fit_recovers_a_known_technology():
    """Synthetic grid: ln fuel = ln(base) - b ln s + ln(1 + aux / p), b and p differing by row (the Prius's
    fuel is exactly 1/s, b = 1; the Sonata's b = 0.8); measurements made at s = 1.3, aux = 700 W are fitted
    back. The surrogate is quadratic in ln s, so a power law in s is exact."""
    s = np.asarray(ph.CAL_SCALE)[:, None]
    aux = np.asarray(ph.CAL_AUX)[None, :]
    base = np.array([5.0, 4.2, 6.1, 7.3])
    b = np.array([1.0, 0.8, 1.0, 0.8])
    p = np.array([9000.0, 20000.0, 12000.0, 30000.0])
    grid = (
        np.log(base)[:, None, None]
        - b[:, None, None] * np.log(s)[None]
        + np.log1p(aux[None] / p[:, None, None])
    )
    meas = np.log(base) - b * math.log(1.3) + np.log1p(700.0 / p)
    params, loss = ph.fit_hev_peer(grid, meas)
    assert params["efficiency_scale"] == pytest.approx(1.3, rel=0.01)  # the fine grid's step is 1 %
    assert params["accessory_power_w"] == pytest.approx(700.0, abs=50.0)  # the quadratic in aux
    assert loss < 0.005
    with pytest.raises(ValueError, match="no vehicle"):
        ph.fit_hev_peer(grid[:0], meas[:0])


def test_calibration_is_per_fold_and_class():
    """Each (fold, class) is fitted without that fold's rows: the fold that holds the one row with a 1.5x
    better engine out is fitted on the others' s = 1; the other fold's fit sees that row."""
    s = np.asarray(ph.CAL_SCALE)[:, None]
    aux = np.asarray(ph.CAL_AUX)[None, :]
    p = np.array([5000.0, 20000.0, 8000.0, 30000.0, 6000.0, 12000.0])  # the accessories' weight, by row
    grid = -np.log(s)[None] + np.log1p(aux[None] / p[:, None, None])
    truth = np.array([1.0, 1.0, 1.0, 1.5, 1.0, 1.0])
    meas = -np.log(truth) + np.log1p(500.0 / p)
    folds = np.array([0, 1, 0, 1, 0, 1])
    classes = np.array(["hev_split"] * 6, dtype=object)
    tech = ph.calibrate_hev_peer(grid, meas, folds, classes, 2, ("hev_split",))
    assert tech[(0, "hev_split")]["n_train"] == tech[(1, "hev_split")]["n_train"] == 3
    # fold 1 held out (rows 1, 3, 5): trained on rows 0, 2, 4, all at s = 1 and 500 W
    assert tech[(1, "hev_split")]["efficiency_scale"] == pytest.approx(1.0, rel=0.01)
    assert tech[(1, "hev_split")]["accessory_power_w"] == pytest.approx(500.0, abs=50.0)
    assert tech[(0, "hev_split")]["train_loss"] > 0.01  # row 3 does not fit the others' technology


@pytest.fixture(scope="module")
def corolla(shared_dir):
    pytest.importorskip("fastsim")
    lst = shared_dir / "data" / "epa" / "22-tstcar.csv"
    if not lst.exists():
        pytest.skip(f"{lst} not found")
    from vpsim.fleet.epa import read_test_car_list

    return {v.key: v for v in read_test_car_list(lst).hev_vehicles}["20-ZE1H#0"]


def test_technology_moves_fuel_the_right_way(corolla):
    """On the power split (the Prius resource) FASTSim's fuel is exactly proportional to 1 / s, and a
    kilowatt more of accessories costs fuel; an unknown parameter or a non-positive scale is refused."""
    d = ph.hev_peer_vehicle(corolla, "udds")
    base = ph.run_hev_peer(d, "udds")["peer_mpg"]
    better = ph.run_hev_peer(ph.with_hev_technology(d, {"efficiency_scale": 1.25}), "udds")["peer_mpg"]
    assert better / base == pytest.approx(1.25, rel=1e-4)
    more = ph.run_hev_peer(ph.with_hev_technology(d, {"accessory_power_w": 2500.0}), "udds")["peer_mpg"]
    assert more < base
    with pytest.raises(ValueError, match="unknown hybrid peer parameter"):
        ph.with_hev_technology(d, {"drivetrain_efficiency_scale": 1.0})
    with pytest.raises(ValueError, match="positive scale"):
        ph.with_hev_technology(d, {"efficiency_scale": 0.0})
    rows = ph.hev_calibration_chunk([(corolla, "udds_hot")])
    assert rows[0]["peer_error"] == "" and rows[0]["log_l100"].shape == (3, 3)
    # the grid's centre is FASTSim's efficiency curve at 1 kW of accessories
    at_1kw = ph.run_hev_peer(ph.with_hev_technology(d, {"accessory_power_w": 1000.0}), "udds")["peer_mpg"]
    assert rows[0]["log_l100"][1, 1] == pytest.approx(math.log(mpg_from_l_per_100km(at_1kw)), abs=1e-6)
