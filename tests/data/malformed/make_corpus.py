"""Write the malformed-input corpus (run from the repository root to regenerate it):

    .venv/bin/python tests/data/malformed/make_corpus.py

One folder per kind of input (station, procedure, product, sim, model: YAML; analyze and
discrepancy: CSV), each file with one defect, and `expected.json`: file -> a piece of text the
one-line error must hold (the field or the problem). tests/test_malformed_corpus.py feeds each
file through the station's command line. The folder api/ belongs to the UI's JSON tests.
"""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from typing import Any

import yaml

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[2]
KINDS = ("station", "procedure", "product", "sim", "model", "analyze", "discrepancy")

BILLION_LAUGHS = (
    'a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]\n'
    "b: &b [*a,*a,*a,*a,*a,*a,*a,*a,*a]\n"
    "c: &c [*b,*b,*b,*b,*b,*b,*b,*b,*b]\n"
    "d: &d [*c,*c,*c,*c,*c,*c,*c,*c,*c]\n"
    "e: &e [*d,*d,*d,*d,*d,*d,*d,*d,*d]\n"
    "f: &f [*e,*e,*e,*e,*e,*e,*e,*e,*e]\n"
    "g: &g [*f,*f,*f,*f,*f,*f,*f,*f,*f]\n"
    "h: &h [*g,*g,*g,*g,*g,*g,*g,*g,*g]\n"
    "i: &i [*h,*h,*h,*h,*h,*h,*h,*h,*h]\n"
)
NAN = float("nan")
INF = float("inf")
HUGE_TEXT = "X" * 20_000


def _base(kind: str) -> dict[str, Any]:
    if kind == "station":
        return {
            "station": {"id": "EOL-T-01", "name": "test station"},
            "output_folder": "runs",
            "results_db": "runs/results.sqlite",
            "instruments": {
                "rate_table": {"address": "127.0.0.1:5020", "timeout_s": 1.0},
                "fixture": {"sockets": 2, "ports": {1: "/dev/ttyUSB1"}},
            },
        }
    if kind == "model":
        return {
            "name": "first_order",
            "bias_dps": 8.6,
            "scale": 1.05,
            "effects": {"k2_quadratic": {"k2_per_dps": 2.0e-6}},
            "uncertainties": {"bias_dps": 0.001},
        }
    path = {
        "procedure": REPO / "config/procedures/eol-rate-table.yaml",
        "product": REPO / "config/products/gyr130.yaml",
        "sim": REPO / "config/sim/article_part.yaml",
    }[kind]
    data = yaml.safe_load(path.read_text(encoding="utf-8"))
    if kind == "procedure":
        data.pop("product", None)  # the test passes --product
    return data


def _set(data: dict[str, Any], dotted: str, value: Any) -> dict[str, Any]:
    out = copy.deepcopy(data)
    node: Any = out
    *parents, last = dotted.split(".")
    for p in parents:
        node = node[int(p)] if isinstance(node, list) else node.setdefault(p, {})
    if isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value
    return out


def _drop(data: dict[str, Any], dotted: str) -> dict[str, Any]:
    out = copy.deepcopy(data)
    node: Any = out
    *parents, last = dotted.split(".")
    for p in parents:
        node = node[p]
    del node[last]
    return out


def _dump(data: Any) -> bytes:
    return yaml.safe_dump(data, sort_keys=False, allow_unicode=True, width=10**9).encode()


# The field holding a name in each YAML kind: huge text, NUL and control characters go there.
NAME_FIELD = {
    "station": "station.id",
    "procedure": "name",
    "product": "product",
    "sim": "parts.0.serial",
    "model": "name",
}


def _yaml_common(kind: str) -> dict[str, tuple[bytes, str]]:
    """Defects every YAML kind gets: file name -> (bytes, expected text in the error)."""
    base = _base(kind)
    name_field = NAME_FIELD[kind]
    text = _dump(base).decode()
    top = next(iter(base))
    # an empty sim config is the defaults (valid); every other kind needs its fields
    empty = {} if kind == "sim" else {
        "empty.yaml": (b"", "mapping"),
        "only_comment.yaml": (b"# nothing here\n", "mapping"),
    }
    return {
        **empty,
        "billion_laughs.yaml": (BILLION_LAUGHS.encode(), "aliases expand"),
        "recursive_alias.yaml": (b"a: &a [1, *a]\n", "recursive"),
        "deep_flow_nesting.yaml": (
            ("x: " + "[" * 5000 + "]" * 5000 + "\n").encode(), "nested more than"
        ),
        "deep_block_nesting.yaml": (
            "".join(f"{'  ' * i}k{i}:\n" for i in range(60)).encode() + b"  " * 60 + b"v: 1\n",
            "nested more than",
        ),
        "invalid_utf8.yaml": (text.encode()[:20] + b"\xff\xfe" + text.encode()[20:], "UTF-8"),
        "utf16.yaml": (text.encode("utf-16"), "UTF-8"),
        "latin1.yaml": (_dump(_set(base, name_field, "Gerät")).decode().encode("latin-1"),
                        "UTF-8"),
        "raw_nul.yaml": (text.encode().replace(b"\n", b"\x00\n", 1), "NUL"),
        "escaped_nul_in_name.yaml": (_dump(_set(base, name_field, "SIM\x00-0001")), "NUL"),
        "escape_char_in_name.yaml": (_dump(_set(base, name_field, "A\x1b[2JB")), "U+001B"),
        "top_level_list.yaml": (b"- 1\n- 2\n", "mapping"),
        "top_level_scalar.yaml": (b"just a string\n", "mapping"),
        "unclosed_bracket.yaml": (f"{top}: [1, 2\n".encode(), "not valid YAML"),
        "tab_indent.yaml": (b"a:\n\t- 1\n", "not valid YAML"),
        "unknown_key.yaml": (_dump({**base, "no_such_field": 1}), "no_such_field"),
        "duplicate_key.yaml": (text.encode() + f"{top}: 1\n".encode(), "appears twice"),
        "python_tag.yaml": (b"a: !!python/object/apply:os.system ['true']\n", "not valid YAML"),
        "many_values.yaml": (f"{top}: [{'1,' * 3000}1]\n".encode(), "more than 2000 values"),
        "many_block_values.yaml": (f"{top}:\n".encode() + b"  - 1\n" * 3000,
                                   "more than 2000 values"),
        "huge_int.yaml": (f"{top}: {'9' * 6000}\n".encode(), "cannot be read"),
        "huge_name.yaml": (_dump(_set(base, name_field, HUGE_TEXT)), "at most"),
        "name_is_mapping.yaml": (
            _dump(_set(base, name_field, {"a": 1})), name_field.split(".")[-1]
        ),
    }


def _station() -> dict[str, tuple[bytes, str]]:
    b = _base("station")
    cases = {
        "timeout_nan.yaml": ("instruments.rate_table.timeout_s", NAN, "timeout_s"),
        "timeout_inf.yaml": ("instruments.rate_table.timeout_s", INF, "timeout_s"),
        "timeout_huge.yaml": ("instruments.rate_table.timeout_s", 1e308, "timeout_s"),
        "timeout_negative.yaml": ("instruments.rate_table.timeout_s", -1.0, "timeout_s"),
        "baud_huge.yaml": ("instruments.fixture.baud", 10**12, "baud"),
        "baud_text.yaml": ("instruments.fixture.baud", "fast", "baud"),
        "sockets_1000.yaml": ("instruments.fixture.sockets", 1000, "sockets"),
        "port_socket_0.yaml": ("instruments.fixture.ports", {0: "/dev/ttyUSB0"}, "ports"),
        "calibration_due_text.yaml": ("instruments.chamber.calibration_due", "soon",
                                      "calibration_due"),
        "address_huge.yaml": ("instruments.chamber.address", HUGE_TEXT, "address"),
        "output_folder_list.yaml": ("output_folder", ["a", "b"], "output_folder"),
        "station_is_text.yaml": ("station", "EOL", "station"),
        "unknown_instrument_key.yaml": ("instruments.supply.volts", 5, "volts"),
    }
    out = {k: (_dump(_set(b, f, v)), e) for k, (f, v, e) in cases.items()}
    out["bad_date.yaml"] = (  # matches YAML's timestamp form: the constructor fails
        _dump(b).replace(
            b"instruments:\n", b"instruments:\n  chamber: {calibration_due: 2026-13-45}\n", 1
        ),
        "cannot be read",
    )
    out["station_missing.yaml"] = (_dump(_drop(b, "station")), "station")
    return out


# where each step entry sits in config/procedures/eol-rate-table.yaml
POWER, FIT, VERIFY = "steps.0", "steps.2", "steps.4"
THERMAL, BIAS, TABLE, STOP = (f"steps.1.steps.{i}" for i in range(4))


def _procedure() -> dict[str, tuple[bytes, str]]:
    b = _base("procedure")
    cases = {
        "dwell_nan.yaml": (f"{BIAS}.dwell_s", NAN, "dwell_s"),
        "dwell_two_days.yaml": (f"{BIAS}.dwell_s", 172_800.0, "dwell_s"),
        "rates_1e308.yaml": (f"{TABLE}.rates_dps", [1e308, -50.0], "rates_dps"),
        "rates_beyond_range.yaml": (f"{TABLE}.rates_dps", [300.0, -200.0], "range"),
        "verify_rate_beyond_range.yaml": (f"{VERIFY}.rates_dps", [-150.0, 251.0], "range"),
        "timeout_inf.yaml": (f"{POWER}.timeout_s", INF, "timeout_s"),
        "setpoint_timeout_huge.yaml": ("chamber.setpoint_timeout_s", 1e12, "setpoint_timeout_s"),
        "stability_timeout_nan.yaml": (f"{THERMAL}.stability_timeout_s", NAN, "timeout_s"),
        "safe_temp_300.yaml": ("chamber.safe_temp_c", 300.0, "safe_temp_c"),
        "safe_temp_nan.yaml": ("chamber.safe_temp_c", NAN, "safe_temp_c"),
        "temperature_1000.yaml": ("conditions.temperatures_c", [25.0, 1000.0], "temperatures_c"),
        "supply_negative.yaml": ("conditions.supplies_v", [-5.0], "supplies_v"),
        "supply_1e6.yaml": ("conditions.supplies_v", [1e6], "supplies_v"),
        "repeats_million.yaml": (f"{TABLE}.repeats", 1_000_000, "repeats"),
        "accel_1e12.yaml": (f"{TABLE}.accel_dps2", 1e12, "accel_dps2"),
        "retries_negative.yaml": (f"{POWER}.retries", -1, "retries"),
        "stop_angle_1000.yaml": (f"{STOP}.stop_angle_deg", 1000.0, "stop_angle_deg"),
        "rates_text.yaml": (f"{TABLE}.rates_dps", "fast", "rates_dps"),
        "rates_300.yaml": (f"{TABLE}.rates_dps", [1.0, -1.0] * 150, "rates_dps"),
        "output_rate_7.yaml": ("output_rate_hz", 7, "output_rate_hz"),
        "step_unknown.yaml": (f"{FIT}.step", "fitt", "unknown step type"),
        "step_setting_unknown.yaml": (f"{BIAS}.dwel_s", 30.0, "dwel_s"),
        "informational_misspelt.yaml": (f"{BIAS}.informational", ["raw_bias_dpz"],
                                        "raw_bias_dpz"),
        "description_nul.yaml": ("description", "line one\x00", "NUL"),
        "lost_fraction_2.yaml": ("stream.max_lost_fraction", 2.0, "max_lost_fraction"),
    }
    out = {k: (_dump(_set(b, f, v)), e) for k, (f, v, e) in cases.items()}
    out["conditions_missing.yaml"] = (_dump(_drop(b, "conditions")), "conditions")
    old_form = yaml.safe_load((REPO / "tests/data/old_form/eol-rate-table.yaml").read_text())
    old_form.pop("product", None)
    loop = {"repeat": 0, "steps": b["steps"][1]["steps"]}
    out["repeat_zero.yaml"] = (_dump(_set(b, "steps.1", loop)), "whole number 1..")
    out["old_section_form.yaml"] = (_dump(old_form), "station procedure convert")
    out["file_over_size_limit.yaml"] = (b"name: " + b"N" * 70_000 + b"\n", "too large")
    return out


def _product() -> dict[str, tuple[bytes, str]]:
    b = _base("product")
    cases = {
        "range_nan.yaml": ("range_dps", NAN, "range_dps"),
        "range_1e308.yaml": ("range_dps", 1e308, "range_dps"),
        "range_negative.yaml": ("range_dps", -250.0, "range_dps"),
        "range_inf.yaml": ("range_dps", INF, "range_dps"),
        "limit_low_above_high.yaml": ("limits.raw_bias_dps", {"low": 5.0, "high": -5.0},
                                      "raw_bias_dps"),
        "limit_high_inf.yaml": ("limits.raw_bias_dps", {"high": INF}, "raw_bias_dps"),
        "limit_empty.yaml": ("limits.raw_bias_dps", {}, "raw_bias_dps"),
        "limit_unknown.yaml": ("limits.no_such_limit", {"high": 1.0}, "no_such_limit"),
        "serial_pattern_bad_regex.yaml": ("serial_pattern", "([", "serial_pattern"),
        "serial_pattern_huge.yaml": ("serial_pattern", "A" * 5000, "serial_pattern"),
        "current_limit_inf.yaml": ("current_limit_a", INF, "current_limit_a"),
        "reference_temperature_1e6.yaml": ("reference_temperature_c", 1e6,
                                           "reference_temperature_c"),
        "reference_supply_zero.yaml": ("reference_supply_v", 0.0, "reference_supply_v"),
        "units_huge.yaml": ("limits.raw_bias_dps.units", HUGE_TEXT, "units"),
    }
    out = {k: (_dump(_set(b, f, v)), e) for k, (f, v, e) in cases.items()}
    out["range_missing.yaml"] = (_dump(_drop(b, "range_dps")), "range_dps")
    return out


def _sim() -> dict[str, tuple[bytes, str]]:
    b = _base("sim")
    cases = {
        "speed_1e-9.yaml": ("speed", 1e-9, "speed"),
        "speed_nan.yaml": ("speed", NAN, "speed"),
        "speed_1e308.yaml": ("speed", 1e308, "speed"),
        "seed_negative.yaml": ("seed", -1, "seed"),
        "seed_huge.yaml": ("seed", 2**70, "seed"),
        "socket_zero.yaml": ("parts.0.socket", 0, "socket"),
        "scale_nan.yaml": ("parts.0.scale", NAN, "scale"),
        "bias_1e308.yaml": ("parts.0.bias_dps", 1e308, "bias_dps"),
        "effect_unknown.yaml": ("parts.0.effects", {"k9": {}}, "k9"),
        "effect_param_inf.yaml": ("parts.0.effects", {"k2_quadratic": {"k2_per_dps": INF}},
                                  "effects"),
        "effect_tau_zero.yaml": ("parts.0.effects", {"sensor_lag": {"tau_s": 0.0}}, "tau_s"),
        "chamber_limits_swapped.yaml": ("chamber", {"setpoint_low_c": 100.0,
                                                    "setpoint_high_c": 0.0}, "setpoint_low_c"),
        "chamber_setpoint_1e6.yaml": ("chamber.setpoint_high_c", 1e6, "setpoint_high_c"),
        "slew_1e308.yaml": ("table.slew_rate_dps", 1e308, "slew_rate_dps"),
        "fifo_1e12.yaml": ("fixture.fifo_bytes", 10**12, "fifo_bytes"),
        "serial_with_space.yaml": ("parts.0.serial", "ART 0001", "serial"),
        "parts_not_list.yaml": ("parts", "ART-0001", "parts"),
        "air_tau_inf.yaml": ("chamber.air_tau_s", INF, "air_tau_s"),
    }
    out = {k: (_dump(_set(b, f, v)), e) for k, (f, v, e) in cases.items()}
    many = copy.deepcopy(b)
    many["parts"] = [{"socket": i + 1, "serial": f"S-{i:04d}"} for i in range(65)]
    out["parts_65.yaml"] = (_dump(many), "parts")
    return out


def _model() -> dict[str, tuple[bytes, str]]:
    b = _base("model")
    cases = {
        "scale_zero.yaml": ("scale", 0.0, "scale"),
        "scale_nan.yaml": ("scale", NAN, "scale"),
        "scale_1e308.yaml": ("scale", 1e308, "scale"),
        "bias_inf.yaml": ("bias_dps", INF, "bias_dps"),
        "effect_unknown.yaml": ("effects", {"k9_magic": {}}, "k9_magic"),
        "effect_param_nan.yaml": ("effects", {"k2_quadratic": {"k2_per_dps": NAN}}, "k2_per_dps"),
        "effect_param_unknown.yaml": ("effects", {"k2_quadratic": {"k3": 1.0}}, "k3"),
        "tilt_180.yaml": ("effects", {"g_sensitivity_tilt": {"tilt_deg": 180.0,
                                                             "g_sens_dps_per_g": 0.1}},
                          "tilt_deg"),
        "uncertainty_unknown.yaml": ("uncertainties", {"nope": 1.0}, "nope"),
        "uncertainty_negative.yaml": ("uncertainties", {"bias_dps": -1.0}, "bias_dps"),
        "reference_temperature_30.yaml": ("reference_temperature_c", 30.0,
                                          "reference_temperature_c"),
        "effects_list.yaml": ("effects", ["k2_quadratic"], "effects"),
    }
    out = {k: (_dump(_set(b, f, v)), e) for k, (f, v, e) in cases.items()}
    out["scale_missing.yaml"] = (_dump(_drop(b, "scale")), "scale")
    return out


def _rate_rows(n: int = 40) -> list[str]:
    return [f"{i * 0.01:.2f},{0.1 * math.sin(i):.6f}" for i in range(n)]


def _analyze() -> dict[str, tuple[bytes, str]]:
    good = ["time_s,rate_dps", *_rate_rows()]

    def csv(lines: list[str]) -> bytes:
        return ("\n".join(lines) + "\n").encode()

    def with_row(i: int, row: str) -> bytes:
        lines = list(good)
        lines[i] = row
        return csv(lines)

    return {
        "empty.csv": (b"", "empty"),
        "blank_lines.csv": (b"\n\n  \n", "empty"),
        "header_only.csv": (b"time_s,rate_dps\n", "too short"),
        "too_few_rows.csv": (csv(good[:5]), "too short"),
        "missing_column.csv": (csv(["time_s,gyro", *_rate_rows()]), "rate_dps"),
        "field_200k.csv": (with_row(3, "0.03," + "9" * 200_000), "field"),
        "not_a_number.csv": (with_row(4, "0.04,abc"), "not a number"),
        "nan.csv": (with_row(5, "0.05,nan"), "NaN"),
        "inf.csv": (with_row(5, "0.05,inf"), "NaN or infinite"),
        "rate_1e308.csv": (with_row(5, "0.05,1e308"), "rate_dps"),
        "time_1e300.csv": (with_row(5, "1e300,0.0"), "time_s"),
        "time_not_increasing.csv": (with_row(6, "0.01,0.0"), "not increasing"),
        "invalid_utf8.csv": (csv(good).replace(b"rate_dps", b"rate_\xffdps"), "UTF-8"),
        "utf16.csv": ("\n".join(good).encode("utf-16"), "UTF-8"),
        "nul_byte.csv": (with_row(7, "0.07,\x001.0"), "not a number"),
        "status_negative.csv": (csv(["time_s,rate_dps,status",
                                     *(r + ",-1" for r in _rate_rows())]), "status"),
        "status_fraction.csv": (csv(["time_s,rate_dps,status",
                                     *(r + ",0.5" for r in _rate_rows())]), "status"),
        "binary_junk.csv": (bytes(range(256)) * 4, "UTF-8"),
        "unterminated_quote.csv": (with_row(10, '0.10,"1.0'), "not a number"),
    }


DISC_HEADER = "time_s,gyro_dps,ref_rate_dps,ref_angle_deg,temp_c,supply_v"


def _disc_rows(n: int = 40) -> list[str]:
    return [f"{i * 0.1:.1f},{(i % 20) * 1.0:.1f},{(i % 20) * 1.0:.1f},0.0,25.0,5.0"
            for i in range(n)]


def _discrepancy() -> dict[str, tuple[bytes, str]]:
    good = [DISC_HEADER, *_disc_rows()]

    def csv(lines: list[str]) -> bytes:
        return ("\n".join(lines) + "\n").encode()

    def with_row(i: int, row: str) -> bytes:
        lines = list(good)
        lines[i] = row
        return csv(lines)

    return {
        "empty.csv": (b"", "empty"),
        "header_only.csv": (csv([DISC_HEADER]), "rows"),
        "missing_column.csv": (csv(["time_s,gyro_dps", *_disc_rows()]), "missing"),
        "duplicate_column.csv": (csv([DISC_HEADER + ",temp_c", *_disc_rows()]), "more than once"),
        "field_200k.csv": (with_row(3, "0.3,1.0,1.0,0.0,25.0," + "5" * 200_000), "field"),
        "header_5k.csv": (csv([DISC_HEADER + "," + "h" * 5_000, *_disc_rows()]), "line 1"),
        "not_a_number.csv": (with_row(4, "0.4,abc,1.0,0.0,25.0,5.0"), "not a number"),
        "nan.csv": (with_row(5, "0.5,nan,1.0,0.0,25.0,5.0"), "finite"),
        "inf.csv": (with_row(5, "0.5,1.0,inf,0.0,25.0,5.0"), "finite"),
        "value_1e308.csv": (with_row(5, "0.5,1e308,1.0,0.0,25.0,5.0"), "plausible"),
        "duplicate_time.csv": (with_row(6, "0.4,1.0,1.0,0.0,25.0,5.0"), "same as"),
        "too_few_rows.csv": (csv(good[:5]), "rows"),
        "short_row.csv": (with_row(7, "0.7,1.0"), "missing"),
        "invalid_utf8.csv": (csv(good).replace(b"gyro_dps", b"gyro_\xffdps"), "UTF-8"),
        "nul_byte.csv": (with_row(8, "0.8,\x001.0,1.0,0.0,25.0,5.0"), "not a number"),
        "unknown_segment_kind.csv": (
            csv([DISC_HEADER + ",segment_kind", *(r + ",wobble" for r in _disc_rows())]),
            "segment_kind",
        ),
        "constant_reference_rate.csv": (
            csv([DISC_HEADER, *(f"{i * 0.1:.1f},1.0,1.0,0.0,25.0,5.0" for i in range(40))]),
            "never changes",
        ),
        "semicolon_bad_decimal.csv": (
            csv(["sep=;", DISC_HEADER.replace(",", ";"),
                 *(r.replace(",", ";") for r in _disc_rows()[:3]), "0,3;1,2,3;1;0;25;5"]),
            "not a number",
        ),
        "binary_junk.csv": (bytes(range(256)) * 4, "UTF-8"),
    }


def corpus() -> dict[str, dict[str, tuple[bytes, str]]]:
    out: dict[str, dict[str, tuple[bytes, str]]] = {}
    specific = {"station": _station, "procedure": _procedure, "product": _product,
                "sim": _sim, "model": _model}
    for kind, make in specific.items():
        out[kind] = {**_yaml_common(kind), **make()}
    out["analyze"] = _analyze()
    out["discrepancy"] = _discrepancy()
    return out


def main() -> None:
    expected: dict[str, str] = {}
    for kind, files in corpus().items():
        folder = HERE / kind
        folder.mkdir(exist_ok=True)
        for old in folder.iterdir():
            old.unlink()
        for name, (data, needle) in sorted(files.items()):
            (folder / name).write_bytes(data)
            expected[f"{kind}/{name}"] = needle
    (HERE / "expected.json").write_text(json.dumps(expected, indent=1, sort_keys=True) + "\n")
    print(f"{len(expected)} files")


if __name__ == "__main__":
    main()
