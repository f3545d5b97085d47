"""Property-based tests of every file loader (hypothesis): whatever the bytes, a loader
returns a validated model or raises its one documented error type, whose every line names
the file, promptly; never a traceback of another type, never a hang.

YAML: station.yaml, procedure, product, sim config, model YAML (random text, random YAML
documents and mutations of the shipped files). CSV: `station analyze` and the discrepancy
CSV (random text and mutations of valid records)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from common.yaml_input import ConfigError
from drivers.sim.config import SimConfigError, load_sim_config
from procedures.loading.config import load_procedure, load_product
from procedures.model.data import load_csv
from procedures.model.model_io import load_model
from station.cli.analyze import read_rate_csv
from station.errors import UserError
from station.station_file import load_settings

REPO = Path(__file__).resolve().parents[1]
SHIPPED = {
    "station": REPO / "config" / "station.yaml",
    "procedure": REPO / "config" / "procedures" / "eol-rate-table.yaml",
    "product": REPO / "config" / "products" / "gyr130.yaml",
    "sim": REPO / "config" / "sim" / "article_part.yaml",
}
LOADERS: dict[str, tuple[Callable[[Path], Any], type[Exception]]] = {
    "station": (load_settings, ConfigError),
    "procedure": (load_procedure, ConfigError),
    "product": (load_product, ConfigError),
    "sim": (load_sim_config, SimConfigError),
    "model": (load_model, ValueError),  # ConfigError, or "neither a built-in nor a file"
}
PROMPT_S = 2.0
SETTINGS = settings(
    max_examples=25,
    deadline=None,  # timed below, with a bound that tolerates a loaded machine
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)

scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(10**30), max_value=10**30),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=40),
)
documents = st.recursive(
    scalars,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4),
        st.dictionaries(st.text(max_size=12), inner, max_size=4),
    ),
    max_leaves=20,
)


def _check(kind: str, path: Path) -> None:
    """Load `path`; the only failure allowed is the documented error, naming the file."""
    load, error = LOADERS[kind]
    t0 = time.monotonic()
    try:
        load(path)
    except error as exc:
        text = str(exc)
        assert text, "an error without a message"
        for line in text.splitlines():
            assert str(path) in line, f"a line of the error does not name the file: {line!r}"
            assert len(line) < 2_000
    assert time.monotonic() - t0 < PROMPT_S


def _mutate(data: bytes, position: int, insert: bytes, cut: int) -> bytes:
    i = position % (len(data) + 1)
    return data[:i] + insert + data[i + cut :]


@pytest.mark.parametrize("kind", sorted(LOADERS))
@SETTINGS
@given(text=st.text(max_size=300))
def test_any_text_is_loaded_or_refused_cleanly(kind: str, text: str, tmp_path: Path) -> None:
    path = tmp_path / f"{kind}.yaml"
    path.write_bytes(text.encode("utf-8", errors="surrogatepass"))
    _check(kind, path)


@pytest.mark.parametrize("kind", sorted(LOADERS))
@SETTINGS
@given(doc=documents)
def test_any_yaml_document_is_loaded_or_refused_cleanly(
    kind: str, doc: Any, tmp_path: Path
) -> None:
    path = tmp_path / f"{kind}.yaml"
    path.write_text(yaml.safe_dump(doc, allow_unicode=True), encoding="utf-8")
    _check(kind, path)


@pytest.mark.parametrize("kind", sorted(SHIPPED))
@SETTINGS
@given(position=st.integers(0, 10_000), insert=st.binary(max_size=12),
       cut=st.integers(0, 8))
def test_damaged_shipped_files_are_loaded_or_refused_cleanly(
    kind: str, position: int, insert: bytes, cut: int, tmp_path: Path
) -> None:
    path = tmp_path / SHIPPED[kind].name
    path.write_bytes(_mutate(SHIPPED[kind].read_bytes(), position, insert, cut))
    # relative paths inside (a procedure's product) must resolve as they do in config/
    if kind == "procedure":
        (tmp_path.parent / "products").mkdir(exist_ok=True)
    _check(kind, path)


@pytest.mark.parametrize("kind", sorted(SHIPPED))
@SETTINGS
@given(field=st.sampled_from(["nan", ".inf", "-.inf", "1e308", "-1e308", "1e-320", "-0",
                              "0x7fffffffffffffff", "'" + "x" * 5000 + "'", "~", "[]", "{}"]),
       which=st.integers(0, 10_000))
def test_any_number_replaced_by_an_extreme_is_refused_or_bounded(
    kind: str, field: str, which: int, tmp_path: Path
) -> None:
    """Replace one number of a shipped file with an extreme value: refused, or still a model
    whose floats are all finite."""
    lines = SHIPPED[kind].read_text(encoding="utf-8").splitlines()
    numeric = [i for i, line in enumerate(lines)
               if ":" in line and _is_number(line.split(":", 1)[1].split("#")[0].strip())]
    i = numeric[which % len(numeric)]
    key = lines[i].split(":", 1)[0]
    lines[i] = f"{key}: {field}"
    path = tmp_path / SHIPPED[kind].name
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    load, error = LOADERS[kind]
    try:
        model = load(path)
    except error as exc:
        assert str(path) in str(exc)
        return
    assert all(math.isfinite(v) for v in _floats(model)), f"{key}: {field} was accepted"


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _floats(obj: Any) -> list[float]:
    if isinstance(obj, tuple) and obj and hasattr(obj[0], "model_dump"):
        obj = obj[0]
    if hasattr(obj, "settings"):
        obj = obj.settings
    if hasattr(obj, "model_dump"):
        obj = obj.model_dump()
    if isinstance(obj, float):
        return [obj]
    if isinstance(obj, dict):
        return [f for v in obj.values() for f in _floats(v)]
    if isinstance(obj, list | tuple):
        return [f for v in obj for f in _floats(v)]
    return []


# ---------------------------------------------------------------- CSV

RATE_HEADER = "time_s,rate_dps"
DISC_HEADER = "time_s,gyro_dps,ref_rate_dps,ref_angle_deg,temp_c,supply_v"
cells = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-(10**400), 10**400).map(str),
    st.text(alphabet=st.characters(blacklist_categories=["Cs"]), max_size=8),
    st.sampled_from(["", '"', '""', "1,5", "\x00", "nan", "-inf", "1e309", "  3 ", "0x10"]),
)


def _rate_csv() -> str:
    return RATE_HEADER + "\n" + "\n".join(
        f"{i * 0.01:.2f},{math.sin(i):.4f}" for i in range(40)
    ) + "\n"


def _disc_csv() -> str:
    return DISC_HEADER + "\n" + "\n".join(
        f"{i * 0.1:.1f},{i % 20:.1f},{i % 20:.1f},{i:.1f},25.0,5.0" for i in range(60)
    ) + "\n"


def _check_csv(kind: str, path: Path) -> None:
    t0 = time.monotonic()
    try:
        if kind == "analyze":
            read_rate_csv(path)
        else:
            load_csv(path)
    except (UserError, ValueError) as exc:
        assert str(path) in str(exc), str(exc)
        assert "\n" not in str(exc), "a CSV error is one line"
    assert time.monotonic() - t0 < PROMPT_S


@pytest.mark.parametrize("kind", ["analyze", "discrepancy"])
@SETTINGS
@given(data=st.binary(max_size=400))
def test_any_bytes_as_csv_are_loaded_or_refused_in_one_line(
    kind: str, data: bytes, tmp_path: Path
) -> None:
    path = tmp_path / "data.csv"
    path.write_bytes(data)
    _check_csv(kind, path)


@pytest.mark.parametrize("kind", ["analyze", "discrepancy"])
@SETTINGS
@given(row=st.integers(0, 80), column=st.integers(0, 7), cell=cells,
       long_field=st.sampled_from([0, 0, 0, 140_000]))
def test_a_damaged_cell_is_loaded_or_refused_in_one_line(
    kind: str, row: int, column: int, cell: str, long_field: int, tmp_path: Path
) -> None:
    lines = (_rate_csv() if kind == "analyze" else _disc_csv()).splitlines()
    r = row % len(lines)
    fields = lines[r].split(",")
    fields[column % len(fields)] = cell + "9" * long_field
    lines[r] = ",".join(fields)
    path = tmp_path / "data.csv"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8", errors="surrogatepass")
    _check_csv(kind, path)
