"""The results database's tables at the newest migration (SQLAlchemy Core).

The migrations under station/db/migrations create these; this module is what the queries use.
Times are ISO-8601 UTC text (`YYYY-MM-DDTHH:MM:SS+00:00`) so that text order is time order in
SQLite and PostgreSQL alike.
"""

from __future__ import annotations

from typing import Any

import sqlalchemy as sa

CAL_KEYS = (
    "bias_dps",
    "bias_temp_coeff_dps_per_c",
    "bias_supply_coeff_dps_per_v",
    "scale",
    "scale_temp_coeff_per_c",
    "scale_supply_coeff_per_v",
)

metadata = sa.MetaData()

runs = sa.Table(
    "runs",
    metadata,
    sa.Column("run_id", sa.Text, primary_key=True),
    sa.Column("serial", sa.Text, nullable=False),
    sa.Column("product", sa.Text, nullable=False),
    sa.Column("verdict", sa.Text, nullable=False),
    sa.Column("reason", sa.Text, nullable=False, server_default=""),
    sa.Column("failed_measurements", sa.Text, nullable=False, server_default="[]"),
    sa.Column("simulated", sa.Integer, nullable=False, server_default="0"),
    sa.Column("started_utc", sa.Text, nullable=False),
    sa.Column("finished_utc", sa.Text),
    sa.Column("station_id", sa.Text, nullable=False, server_default=""),
    sa.Column("operator", sa.Text, nullable=False, server_default=""),
    sa.Column("software_version", sa.Text, nullable=False, server_default=""),
    sa.Column("procedure_name", sa.Text, nullable=False, server_default=""),
    sa.Column("procedure_sha256", sa.Text, nullable=False, server_default=""),
    sa.Column("product_sha256", sa.Text, nullable=False, server_default=""),
    sa.Column("raw_sha256", sa.Text, nullable=False, server_default=""),
    sa.Column("folder", sa.Text, nullable=False),
    *[
        c
        for k in CAL_KEYS
        for c in (sa.Column(f"cal_{k}", sa.Double), sa.Column(f"cal_{k}_u", sa.Double))
    ],
    # schema 2 (migration 0002): the line
    sa.Column("work_order", sa.Text, nullable=False, server_default=""),
    sa.Column("lot", sa.Text, nullable=False, server_default=""),
    sa.Column("attempt", sa.Integer, nullable=False, server_default="1"),
    sa.Column("first_run_id", sa.Text, nullable=False, server_default=""),
    sa.Column("unit_verdict", sa.Text, nullable=False, server_default=""),
    sa.Column("unit_tests", sa.Integer, nullable=False, server_default="1"),
    # schema 4 (migration 0004): three-axis parts
    sa.Column("axes", sa.Integer, nullable=False, server_default="1"),
    # schema 5 (migration 0005): the socket the part sat in (0: not recorded)
    sa.Column("socket", sa.Integer, nullable=False, server_default="0"),
)

# Schema 4: a three-axis calibration, one row per element. quantity is the record's key
# (bias_dps, matrix, g_sensitivity_dps_per_mps2, bias_temp_coeff_dps_per_c, ...), axis the
# output axis (x, y, z), column_axis the matrix column (None for a vector).
calibration_elements = sa.Table(
    "calibration_elements",
    metadata,
    sa.Column(
        "run_id", sa.Text, sa.ForeignKey("runs.run_id", ondelete="CASCADE"), primary_key=True
    ),
    sa.Column("seq", sa.Integer, primary_key=True),
    sa.Column("quantity", sa.Text, nullable=False),
    sa.Column("axis", sa.Text, nullable=False),
    sa.Column("column_axis", sa.Text),
    sa.Column("value", sa.Double),
    sa.Column("uncertainty_k2", sa.Double),
)

measurements = sa.Table(
    "measurements",
    metadata,
    sa.Column(
        "run_id", sa.Text, sa.ForeignKey("runs.run_id", ondelete="CASCADE"), primary_key=True
    ),
    sa.Column("seq", sa.Integer, primary_key=True),
    sa.Column("name", sa.Text, nullable=False),
    sa.Column("condition", sa.Text),
    sa.Column("value", sa.Double),
    sa.Column("units", sa.Text, nullable=False, server_default=""),
    sa.Column("low", sa.Double),
    sa.Column("high", sa.Double),
    sa.Column("marginal_low", sa.Double),
    sa.Column("marginal_high", sa.Double),
    sa.Column("outcome", sa.Text, nullable=False),
    sa.Column("uncertainty_k2", sa.Double),
)

# Store-and-forward: a run's row is queued here (version bumped) each time it is written
# locally; the sync marks the version it delivered to the central database.
outbox = sa.Table(
    "outbox",
    metadata,
    sa.Column("run_id", sa.Text, primary_key=True),
    sa.Column("version", sa.Integer, nullable=False),
    sa.Column("sent_version", sa.Integer, nullable=False, server_default="0"),
    sa.Column("queued_utc", sa.Text, nullable=False),
    sa.Column("sent_utc", sa.Text),
)

# The central database's view of each station: written by that station's sync.
stations = sa.Table(
    "stations",
    metadata,
    sa.Column("station_id", sa.Text, primary_key=True),
    sa.Column("last_seen_utc", sa.Text, nullable=False),
    sa.Column("state", sa.Text, nullable=False, server_default=""),
    sa.Column("pending_runs", sa.Integer, nullable=False, server_default="0"),
    sa.Column("software_version", sa.Text, nullable=False, server_default=""),
)

RUN_COLUMNS = tuple(c.name for c in runs.columns)
MEASUREMENT_COLUMNS = tuple(c.name for c in measurements.columns)

# Schema 6 (migration 0006): rollups kept up to date as runs are written (station.db.rollups).
# One row per hour (UTC, `YYYY-MM-DDTHH`), station, product, lot, work order and simulated
# flag; the day and the shift are read from the hour. Yields count a unit in the row of its
# first test (attempt 1, finished).
ROLLUP_KEY = ("hour_utc", "station_id", "product", "lot", "work_order", "simulated")
RUN_COUNTS = ("runs", "passed", "failed", "errored", "aborted", "running",
              "units", "unit_tests", "first_pass", "final_pass")


def _key_columns(keys: tuple[str, ...]) -> list[sa.Column[Any]]:
    return [sa.Column(k, sa.Integer if k == "simulated" else sa.Text, primary_key=True)
            for k in keys]


def _run_rollup(name: str, keys: tuple[str, ...]) -> sa.Table:
    return sa.Table(
        name, metadata, *_key_columns(keys),
        *[sa.Column(c, sa.Integer, nullable=False, server_default="0") for c in RUN_COUNTS],
    )


rollup_runs = _run_rollup("rollup_runs", ROLLUP_KEY)

# Each measurement (name, condition "" when none) of the first tests in a rollup_runs key:
# count, sum and sum of squares (mean and sd), extremes, the widest limits judged against and
# how many values fell below / above them (Cpk and its fallout).
MEASUREMENT_SUMS = ("n", "total", "total_sq", "below", "above")
MEASUREMENT_BOUNDS = ("vmin", "vmax", "low", "high")


def _measurement_rollup(name: str, keys: tuple[str, ...]) -> sa.Table:
    return sa.Table(
        name, metadata, *_key_columns(keys),
        sa.Column("name", sa.Text, primary_key=True),
        sa.Column("condition", sa.Text, primary_key=True),
        sa.Column("units", sa.Text, nullable=False, server_default=""),
        *[sa.Column(c, sa.Double if c.startswith("total") else sa.Integer, nullable=False,
                    server_default="0") for c in MEASUREMENT_SUMS],
        *[sa.Column(c, sa.Double) for c in MEASUREMENT_BOUNDS],
    )


rollup_measurements = _measurement_rollup("rollup_measurements", ROLLUP_KEY)

# Schema 7 (migration 0007): the same counts and sums at coarser grains, kept in the same
# transaction, so a long range reads days instead of hours. Each grain is named by its key:
# day_utc (`YYYY-MM-DD`) or hour_utc, then the dimensions it keeps. The yield tables need the
# station per day, the lot and work order per day, and the hour (the shift) per product.
ROLLUP_GRAINS = {
    "rollup_runs_day_station": ("day_utc", "station_id", "product", "simulated"),
    "rollup_runs_day_lot": ("day_utc", "lot", "work_order", "product", "simulated"),
    "rollup_runs_hour_product": ("hour_utc", "product", "simulated"),
}
MEASUREMENT_GRAINS = {"rollup_measurements_day_product": ("day_utc", "product", "simulated")}
# Every rollup table, coarsest first: a query reads the first that answers it
RUN_ROLLUPS = (*[_run_rollup(n, k) for n, k in ROLLUP_GRAINS.items()], rollup_runs)
MEASUREMENT_ROLLUPS = (*[_measurement_rollup(n, k) for n, k in MEASUREMENT_GRAINS.items()],
                       rollup_measurements)
