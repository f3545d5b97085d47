"""Schema 3: what a factory's MES reads, as views in the shape of NI TestStand's database
(UUT_RESULT, STEP_RESULT, MEAS_NUMERICLIMIT), over the runs and measurements tables.

Unquoted names: PostgreSQL folds them to lower case, so `SELECT * FROM UUT_RESULT` works the
same on both databases. docs/line-database.md lists the columns.

Revision ID: 0003
"""

from __future__ import annotations

from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None

_UUT_RESULT = """
CREATE VIEW UUT_RESULT AS SELECT
    run_id AS ID,
    station_id AS STATION_ID,
    lot AS BATCH_SERIAL_NUMBER,
    work_order AS WORK_ORDER,
    serial AS UUT_SERIAL_NUMBER,
    product AS PART_NUMBER,
    operator AS USER_LOGIN_NAME,
    started_utc AS START_DATE_TIME,
    finished_utc AS FINISH_DATE_TIME,
    CASE verdict WHEN 'PASS' THEN 'Passed' WHEN 'FAIL' THEN 'Failed'
        WHEN 'ERROR' THEN 'Error' WHEN 'ABORTED' THEN 'Terminated' ELSE 'Running' END
        AS UUT_STATUS,
    reason AS UUT_ERROR_MESSAGE,
    attempt AS ATTEMPT,
    first_run_id AS FIRST_UUT_RESULT,
    procedure_name AS SEQUENCE_NAME,
    software_version AS SOFTWARE_VERSION
FROM runs
"""

_STEP_RESULT = """
CREATE VIEW STEP_RESULT AS SELECT
    run_id || ':' || CAST(seq AS TEXT) AS ID,
    run_id AS UUT_RESULT,
    seq + 1 AS ORDER_NUMBER,
    CASE WHEN condition IS NULL OR condition = '' THEN name
        ELSE name || ' @ ' || condition END AS STEP_NAME,
    name AS MEASUREMENT_NAME,
    condition AS STEP_CONDITION,
    'NumericLimitTest' AS STEP_TYPE,
    'Main' AS STEP_GROUP,
    CASE outcome WHEN 'PASS' THEN 'Passed' WHEN 'MARGINAL' THEN 'Passed'
        WHEN 'FAIL' THEN 'Failed' ELSE 'Skipped' END AS STATUS,
    outcome AS OUTCOME
FROM measurements
"""

_MEAS_NUMERICLIMIT = """
CREATE VIEW MEAS_NUMERICLIMIT AS SELECT
    run_id || ':' || CAST(seq AS TEXT) AS STEP_RESULT,
    name AS NAME,
    value AS DATA,
    units AS UNITS,
    low AS LOW_LIMIT,
    high AS HIGH_LIMIT,
    CASE WHEN low IS NOT NULL AND high IS NOT NULL THEN 'GELE'
        WHEN low IS NOT NULL THEN 'GE' WHEN high IS NOT NULL THEN 'LE' ELSE 'LOG' END
        AS COMP_OPERATOR,
    uncertainty_k2 AS EXPANDED_UNCERTAINTY,
    CASE outcome WHEN 'PASS' THEN 'Passed' WHEN 'MARGINAL' THEN 'Passed'
        WHEN 'FAIL' THEN 'Failed' ELSE 'Skipped' END AS STATUS
FROM measurements
"""


def upgrade() -> None:
    for sql in (_UUT_RESULT, _STEP_RESULT, _MEAS_NUMERICLIMIT):
        op.execute(sql)


def downgrade() -> None:
    for view in ("MEAS_NUMERICLIMIT", "STEP_RESULT", "UUT_RESULT"):
        op.execute(f"DROP VIEW {view}")
