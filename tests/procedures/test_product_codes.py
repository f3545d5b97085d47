"""The part's code format comes from the product file: gyr130 reads exactly as before, and a
product with another format (signed, narrower codes, other scales) converts its frames
correctly through the parser and the acquisition."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from common.clock import ScaledClock
from common.yaml_input import ConfigError
from drivers import fixture_protocol as fp
from drivers.part_codes import ADIS16130, CodeFormat
from drivers.protocols import SampleBlock
from procedures.loading.config import load_product
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import PartRun
from procedures.runtime.streams import PartStream
from tests.procedures.test_streams import FakeLink

CONFIG = Path(__file__).resolve().parents[2] / "config"
GYR130 = CONFIG / "products" / "gyr130.yaml"

# a part unlike the ADIS16130: 16-bit two's complement rate, 80 counts per deg/s; 12-bit
# two's complement temperature, 0 at 25 C, 16 counts per C
OTHER_CODES = {
    "rate_width_bits": 16,
    "rate_signed": True,
    "rate_zero_code": 0,
    "rate_counts_per_dps": 80.0,
    "temp_width_bits": 12,
    "temp_signed": True,
    "temp_zero_code": 0,
    "temp_zero_c": 25.0,
    "temp_counts_per_c": 16.0,
}


def _product(tmp_path: Path, codes: dict | None, range_dps: float = 250.0) -> Path:
    data = yaml.safe_load(GYR130.read_text())
    data["range_dps"] = range_dps
    if codes is None:
        data.pop("codes", None)
    else:
        data["codes"] = codes
    path = tmp_path / "product.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _frames_through_stream(codes: CodeFormat, rate_code, temp_code, run_codes) -> PartStream:
    """Frames on the wire -> parser -> a stream whose run context has `run_codes`."""
    n = rate_code.size
    wire = fp.encode_samples(np.arange(n), np.arange(n) * 10_000, rate_code, temp_code,
                             np.zeros(n, dtype=np.int64))
    res = fp.FrameParser().feed(wire)
    assert res.seq.size == n and res.frames_corrupted == 0
    link = FakeLink()
    link.blocks.append(SampleBlock(res.seq, res.time_s, res.rate_code, res.temp_code, res.status))
    stream = PartStream(1, link, ScaledClock(1.0))  # type: ignore[arg-type]
    product = SimpleNamespace(codes=run_codes)
    part = PartRun(socket=1, serial="X", folder=Path("."), record=None,  # type: ignore[arg-type]
                   stream=stream)
    bench = SimpleNamespace(clock=ScaledClock(1.0), table=None, chamber=None)
    RunContext(bench, None, product, [part])  # type: ignore[arg-type]
    stream.start()
    assert stream.poll() == n
    return stream


def test_gyr130_states_the_adis16130_codes_and_old_files_default_to_them(tmp_path: Path) -> None:
    product, _ = load_product(GYR130)
    assert product.codes == ADIS16130
    old, _ = load_product(_product(tmp_path, None))  # a product file from before `codes:`
    assert old.codes == ADIS16130
    # the product's conversion is the one the bench's part and fixture_protocol use
    rng = np.random.default_rng(3)
    codes = rng.integers(0, fp.CODE_MAX + 1, 1000)
    assert np.array_equal(product.codes.rate_code_to_dps(codes), fp.rate_code_to_dps(codes))
    assert np.array_equal(product.codes.temp_code_to_c(codes), fp.temp_code_to_c(codes))
    assert fp.rate_code_to_dps(fp.RATE_ZERO_CODE) == 0.0


def test_gyr130_through_the_acquisition_gives_the_same_numbers_as_before() -> None:
    product, _ = load_product(GYR130)
    rate = np.linspace(-300.0, 300.0, 601)
    temp = np.linspace(-40.0, 85.0, 601)
    rate_code, temp_code = fp.rate_dps_to_code(rate), fp.temp_c_to_code(temp)
    stream = _frames_through_stream(product.codes, rate_code, temp_code, product.codes)
    w = stream.window(-1.0, 1e9)
    # bit-identical to the fixed ADIS16130 formula the acquisition used before
    assert np.array_equal(w["rate_dps"], (rate_code - 8_388_608) / 23_488.0)
    assert np.array_equal(w["temp_c"], (temp_code - 8_036_283) / 14_093.0)
    inside = np.abs(rate) < 250.0
    assert np.allclose(w["rate_dps"][inside], rate[inside], atol=0.5 / 23_488.0)


def test_a_product_with_another_code_format_converts_its_frames(tmp_path: Path) -> None:
    product, _ = load_product(_product(tmp_path, OTHER_CODES, range_dps=300.0))
    codes = product.codes
    assert codes.rate_signed and codes.rate_width_bits == 16
    rate = np.array([-300.0, -123.4567, -0.0125, 0.0, 0.0125, 99.9, 300.0, 500.0, -500.0])
    temp = np.array([-40.0, -10.0, 0.0, 24.9375, 25.0, 60.0, 85.0, 25.5, 20.0])
    rate_code, temp_code = codes.rate_dps_to_code(rate), codes.temp_c_to_code(temp)
    assert rate_code.max() < 1 << 16 and temp_code.max() < 1 << 12  # right-aligned on the wire
    stream = _frames_through_stream(codes, rate_code, temp_code, codes)
    w = stream.window(-1.0, 1e9)
    fits = np.abs(rate) < 32768 / 80.0
    assert np.allclose(w["rate_dps"][fits], rate[fits], atol=0.5 / 80.0)
    # beyond the 16-bit code the part clips at its rails, with the sign kept
    assert w["rate_dps"][-2] == pytest.approx(32767 / 80.0)
    assert w["rate_dps"][-1] == pytest.approx(-32768 / 80.0)
    assert np.allclose(w["temp_c"], temp, atol=0.5 / 16.0)
    # the same frames read with the ADIS16130's format would be nonsense: the format matters
    assert not np.allclose(ADIS16130.rate_code_to_dps(rate_code)[fits], rate[fits], atol=1.0)


def test_a_fixture_that_sign_extends_narrow_codes_reads_the_same(tmp_path: Path) -> None:
    codes = CodeFormat(**OTHER_CODES)
    rate = np.array([-250.0, -1.0, 1.0, 250.0])
    value = np.rint(rate * 80.0).astype(np.int64)  # the part's signed 16-bit codes
    extended = value & 0xFFFFFF  # sign-extended to the 24-bit field
    stream = _frames_through_stream(codes, extended, np.zeros(4, dtype=np.int64), codes)
    assert np.allclose(stream.window(-1.0, 1e9)["rate_dps"], rate)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"rate_counts_per_dps": 0.0}, r"codes\.rate_counts_per_dps: .*counts per unit"),
        ({"temp_counts_per_c": ".nan"}, r"codes\.temp_counts_per_c"),
        ({"rate_zero_code": 70000}, r"codes: .*rate_zero_code 70000 is not a 16-bit signed"),
        ({"temp_zero_code": -1, "temp_signed": False},
         r"temp_zero_code -1 is not a 12-bit unsigned"),
        ({"rate_width_bits": 32}, r"codes\.rate_width_bits"),
        ({"rate_counts_per_dps": 200.0}, r"codes: the rate code reaches only .*\+/-250"),
        ({"offset": 3}, r"codes\.offset"),
    ],
)
def test_bad_code_formats_are_refused_with_file_and_line(
    tmp_path: Path, change: dict, message: str
) -> None:
    path = _product(tmp_path, OTHER_CODES)
    text = path.read_text()
    for key, value in change.items():
        if f"  {key}:" in text:
            text = "\n".join(
                f"  {key}: {value}" if line.startswith(f"  {key}:") else line
                for line in text.splitlines()
            )
        else:
            text = text.replace("codes:\n", f"codes:\n  {key}: {value}\n")
    path.write_text(text)
    with pytest.raises(ConfigError, match=message) as info:
        load_product(path)
    assert str(info.value).startswith(f"{path}:")
