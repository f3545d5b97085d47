"""raw.h5: the per-sample encoder column added after the format's first files."""

from pathlib import Path

import h5py
import numpy as np

from procedures.runtime.rawdata import RawDataWriter, read_raw

SAMPLE = {
    "time_s": [0.01, 0.02], "seq": [0, 1], "rate_code": [1, 2], "temp_code": [3, 4],
    "status": [32, 32], "rate_dps": [0.1, 0.2], "temp_c": [25.0, 25.1],
    "station_time_s": [5.01, 5.02],
}


def test_encoder_counts_round_trip_and_default_to_zero(tmp_path: Path) -> None:
    path = tmp_path / "raw.h5"
    with RawDataWriter(path, {"serial": "X"}) as w:
        w.append("samples", **SAMPLE, encoder_counts=[4294967295, 7])
        w.append("samples", **SAMPLE)  # a writer without the column: zeros
    s = read_raw(path)["samples"]
    assert s["encoder_counts"].tolist() == [4294967295, 7, 0, 0]


def test_a_file_written_before_the_column_existed_reads_as_not_latched(tmp_path: Path) -> None:
    path = tmp_path / "raw.h5"
    with RawDataWriter(path, {"serial": "X"}) as w:
        w.append("samples", **SAMPLE)
    with h5py.File(path, "a") as f:
        del f["samples/encoder_counts"]
    s = read_raw(path)["samples"]
    assert s["encoder_counts"].tolist() == [0, 0]
    assert np.array_equal(s["seq"], [0, 1])
