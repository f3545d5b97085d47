"""Load-time checks of the new step types and fit.order: settings validated, an order the
part cannot store or too few temperatures for it refused with file:line, the new
measurements need product limits (or informational)."""

from __future__ import annotations

from pathlib import Path

import pytest

from common.yaml_input import ConfigError
from procedures.loading.config import check_procedure_for_product, load_procedure, load_product
from procedures.steps.registry import step_type

DATA = Path(__file__).resolve().parents[1] / "data" / "newsteps"
SOURCE = (DATA / "turn_on_order2_stop.yaml").read_text()
PRODUCT = (DATA / "gyr130_order2.yaml").read_text()


def _check(tmp_path: Path, procedure: str, product: str = PRODUCT) -> list[str]:
    (tmp_path / "gyr130_order2.yaml").write_text(product)
    path = tmp_path / "proc.yaml"
    path.write_text(procedure)
    proc, proc_file = load_procedure(path)
    prod, prod_file = load_product(tmp_path / "gyr130_order2.yaml")
    return check_procedure_for_product(proc, proc_file, prod, prod_file)


def test_the_shipped_test_procedure_loads(tmp_path: Path) -> None:
    warnings = _check(tmp_path, SOURCE)
    assert not any("turn_on" in w or "warm_up" in w for w in warnings)


def test_the_step_types_are_registered_with_their_pinned_measurements() -> None:
    turn_on, warm_up = step_type("turn_on_repeatability"), step_type("warm_up")
    assert [d.name for d in turn_on.measurements(turn_on.Settings())] == [
        "turn_on_bias_repeatability_dps"]
    assert [d.name for d in warm_up.measurements(warm_up.Settings())] == ["warm_up_time_s"]
    fit = step_type("fit")
    names = {d.name for d in fit.measurements(fit.Settings(order=3))}
    assert {"bias_temp_coeff3_dps_per_c3", "scale_temp_coeff2_per_c2"} <= names


def test_an_order_the_part_cannot_store_is_a_load_error(tmp_path: Path) -> None:
    product = PRODUCT.replace("fit_orders: [1, 2]", "fit_orders: [1]")
    with pytest.raises(ConfigError) as info:
        _check(tmp_path, SOURCE, product)
    msg = str(info.value)
    assert "proc.yaml:" in msg and "order 2 cannot be stored" in msg
    assert "calibration.fit_orders" in msg


def test_too_few_temperatures_for_the_order_is_a_load_error(tmp_path: Path) -> None:
    two = SOURCE.replace("temperatures_c: [25.0, 35.0, 45.0]", "temperatures_c: [25.0, 45.0]")
    with pytest.raises(ConfigError, match="order-2 fit needs 3 temperatures"):
        _check(tmp_path, two)


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [("  turn_ons: 5\n", "  turn_ons: 2\n", "turn_ons"),
     ("  band_dps: 0.01\n", "  band_dps: 0.01\n  band: 3\n", "band"),
     ("  order: 2\n", "  order: 4\n", "order")],
)
def test_bad_settings_are_refused_with_file_and_line(
    tmp_path: Path, old: str, new: str, match: str
) -> None:
    assert old in SOURCE
    with pytest.raises(ConfigError, match=match) as info:
        _check(tmp_path, SOURCE.replace(old, new))
    assert "proc.yaml:" in str(info.value)


def test_a_new_measurement_without_a_product_limit_is_refused(tmp_path: Path) -> None:
    product = PRODUCT.replace("  warm_up_time_s:", "  # warm_up_time_s:")
    with pytest.raises(ConfigError, match="warm_up_time_s"):
        _check(tmp_path, SOURCE, product)
