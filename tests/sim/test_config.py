from pathlib import Path

import pytest

from drivers.sim.config import PartSpec, SimConfigError, load_sim_config, parse_sim_config
from drivers.sim.population import draw_population, resolve_part

REPO = Path(__file__).resolve().parents[2]


def test_shipped_configs_load() -> None:
    for path in sorted((REPO / "config" / "sim").glob("*.yaml")):
        cfg = load_sim_config(path)
        assert cfg.parts, path
    eight = load_sim_config(REPO / "config" / "sim" / "eight_sockets.yaml")
    assert eight.socket_count == 8


def test_population_is_deterministic_per_serial_and_differs_between_serials() -> None:
    a1, a2, b = draw_population("SIM-A"), draw_population("SIM-A"), draw_population("SIM-B")
    assert a1 == a2
    assert a1["bias_dps"] != b["bias_dps"]
    assert 0.3 <= a1["arw_deg_per_sqrt_h"] <= 2.5
    assert 5.0 <= a1["bias_instability_deg_per_h"] <= 25.0


def test_population_spread_matches_method_md() -> None:
    draws = [draw_population(f"P-{i}") for i in range(400)]
    biases = [d["bias_dps"] for d in draws]
    scales = [d["scale"] for d in draws]
    import numpy as np

    assert 1.6 < float(np.std(biases)) < 2.4  # sigma about 2 deg/s
    assert 0.016 < float(np.std(scales)) < 0.024  # sigma about 2 %
    tcs = np.abs([d["bias_temp_coeff_dps_per_c"] for d in draws])
    assert tcs.min() >= 0.005 and tcs.max() <= 0.01


def test_given_parameters_override_the_population() -> None:
    spec = PartSpec(
        socket=1,
        serial="SIM-0001",
        bias_dps=8.6,
        scale=1.0567,
        effects={"bias_temperature": {"bias_temp_coeff_dps_per_c": 0.0}},
    )
    p = resolve_part(spec)
    assert p.bias_dps == 8.6 and p.scale == 1.0567
    assert p.bias_temp_coeff_dps_per_c == 0.0
    drawn = draw_population("SIM-0001")
    assert p.arw_deg_per_sqrt_h == drawn["arw_deg_per_sqrt_h"]


@pytest.mark.parametrize(
    ("data", "needle"),
    [
        (
            {"parts": [{"socket": 1, "serial": "X", "effects": {"k9": {}}}]},
            "unknown effect id 'k9'",
        ),
        ({"parts": [{"socket": 1, "serial": "X", "effects": {"k2_quadratic": {}}}]}, "k2_per_dps"),
        ({"parts": [{"socket": 1, "serial": "X", "scale": -1}]}, "parts.0.scale"),
        ({"parts": [{"socket": 1, "serial": "X"}, {"socket": 1, "serial": "Y"}]}, "socket 1"),
        ({"speed": 0}, "speed"),
        ({"parts": [{"socket": 1, "serial": "X", "bias": 3}]}, "parts.0.bias"),
    ],
)
def test_bad_config_names_the_field(data: dict, needle: str) -> None:
    with pytest.raises(SimConfigError) as err:
        parse_sim_config(data, "my.yaml")
    assert needle in str(err.value)
    assert str(err.value).startswith("my.yaml")


def test_unreadable_and_invalid_yaml_files(tmp_path: Path) -> None:
    with pytest.raises(SimConfigError, match="cannot read"):
        load_sim_config(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("parts: [\n")
    with pytest.raises(SimConfigError, match="not valid YAML"):
        load_sim_config(bad)
    lst = tmp_path / "list.yaml"
    lst.write_text("- 1\n- 2\n")
    with pytest.raises(SimConfigError, match="mapping"):
        load_sim_config(lst)
