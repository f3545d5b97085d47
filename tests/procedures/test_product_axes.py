from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from pydantic import ValidationError

from procedures.loading.config import ProductConfig

ROOT = Path(__file__).resolve().parents[2]


def _load(name: str) -> ProductConfig:
    return ProductConfig.model_validate(yaml.safe_load((ROOT / name).read_text()))


def test_existing_product_is_single_axis_and_three_axis_product_loads() -> None:
    assert _load("config/products/gyr130.yaml").axes == 1
    imu = _load("config/products/imu3.yaml")
    assert imu.axes == 3
    assert imu.limits.misalignment_mrad is not None
    assert imu.limits.g_sensitivity_dps_per_mps2 is not None


def test_axes_other_than_one_or_three_are_refused() -> None:
    data = yaml.safe_load((ROOT / "config/products/imu3.yaml").read_text())
    data["axes"] = 2
    with pytest.raises(ValidationError, match="axes"):
        ProductConfig.model_validate(data)
