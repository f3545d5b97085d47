"""The run record: what `record.json` in every run folder holds.

Written by the station's engine, read by reports (certificate, lot report), the results
database and the discrepancy workflow. Keys pinned in docs/interfaces.md (`verdict`,
`dut.serial`, `procedure.sha256`, `measurements[*].{name,value,units,low,high,outcome}`,
`calibration.*`) are never renamed or removed; add fields, never take them away.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import re
import tempfile
from enum import StrEnum
from pathlib import Path
from typing import Any

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    SerializerFunctionWrapHandler,
    model_serializer,
    model_validator,
)

from procedures.runtime.results import (
    Analysis,
    Verification,
    analysis_from_format_1,
    verification_from_format_1,
)

log = logging.getLogger(__name__)

RECORD_FORMAT = "gyrocal-record/2"  # typed analysis and verification (runtime/results.py)
RECORD_FORMAT_1 = "gyrocal-record/1"  # free dicts; read through the converter
RECORD_FILE = "record.json"
MAX_RECORD_BYTES = 64 * 2**20  # read_record reads no more (a record is tens of kB)
RAW_DATA_FILE = "raw.h5"
CERTIFICATE_FILE = "certificate.pdf"


class StorageError(OSError):
    """A file of a run folder could not be written: the disk is full (ENOSPC), read-only
    (EROFS) or failing (EIO). The message names the file; the run ends ERROR with it."""

    def __str__(self) -> str:
        what = self.strerror or "write failed"
        return f"cannot write {self.filename}: {what}"


def storage_error(path: Path | str, exc: BaseException) -> StorageError:
    """`exc` (an OSError, or h5py's RuntimeError carrying 'errno = N') as a StorageError
    naming `path`."""
    if isinstance(exc, StorageError):
        return exc
    code = getattr(exc, "errno", None)
    if not isinstance(code, int):
        found = re.search(r"errno = (\d+)", str(exc))
        code = int(found.group(1)) if found else errno.EIO
    return StorageError(code, os.strerror(code), str(path))


def os_error_text(exc: OSError) -> str:
    """An OSError in one line naming its file: 'cannot write PATH: No space left on device'
    for a StorageError, 'PATH: Permission denied' otherwise."""
    if isinstance(exc, StorageError) or not exc.filename:
        return str(exc)
    return f"{exc.filename}: {exc.strerror or exc}"


class Verdict(StrEnum):
    PASS = "PASS"
    FAIL = "FAIL"
    ERROR = "ERROR"
    ABORTED = "ABORTED"
    RUNNING = "RUNNING"  # only while the run is in progress; a crash leaves it, marked ERROR later


class Outcome(StrEnum):
    PASS = "PASS"
    MARGINAL = "MARGINAL"  # inside the limits but inside the marginal band: counts as pass, flagged
    FAIL = "FAIL"
    NOT_MEASURED = "NOT_MEASURED"


class _Model(BaseModel):
    model_config = ConfigDict(extra="allow")


class FileRef(_Model):
    path: str
    name: str = ""
    version: str = ""
    sha256: str


class Dut(_Model):
    serial: str
    socket: int = 1
    product: str = ""
    part_serial_register: str | None = None


class InstrumentRecord(_Model):
    role: str  # rate_table, chamber, supply, fixture_<socket>
    manufacturer: str = ""
    model: str = ""
    serial: str = ""
    firmware: str = ""
    address: str = ""
    calibration_due: str | None = None  # ISO date
    calibration_overdue: bool = False


class Measurement(_Model):
    name: str
    value: float | None
    units: str
    low: float | None = None
    high: float | None = None
    marginal_low: float | None = None
    marginal_high: float | None = None
    outcome: Outcome
    uncertainty_k2: float | None = None
    condition: str | None = None
    description: str = ""


class Coefficient(_Model):
    value: float
    uncertainty_k2: float


class Calibration(_Model):
    bias_dps: Coefficient
    bias_temp_coeff_dps_per_c: Coefficient
    bias_supply_coeff_dps_per_v: Coefficient
    scale: Coefficient
    scale_temp_coeff_per_c: Coefficient
    scale_supply_coeff_per_v: Coefficient
    reference_temperature_c: float = 25.0
    reference_supply_v: float = 5.0
    interaction_check: dict[str, float] | None = None  # the spare degree of freedom of the 2x2
    readback_ok: bool | None = None
    readback: dict[str, float] | None = None
    # beyond first order in temperature (the `fit` step's `order: 2` or `3`); absent otherwise
    bias_temp_coeff2_dps_per_c2: Coefficient | None = None
    bias_temp_coeff3_dps_per_c3: Coefficient | None = None
    scale_temp_coeff2_per_c2: Coefficient | None = None
    scale_temp_coeff3_per_c3: Coefficient | None = None
    fit_order: int | None = None  # 2 or 3 above first order; absent for a first-order fit

    @model_serializer(mode="wrap")
    def _as_written(self, handler: SerializerFunctionWrapHandler) -> Any:
        """A first-order fit's record has no higher-order keys (as format 1 wrote it)."""
        data = handler(self)
        if not isinstance(data, dict):
            return data
        drop = (*HIGHER_ORDER_TERMS, "fit_order")
        return {k: v for k, v in data.items() if not (k in drop and v is None)}


HIGHER_ORDER_TERMS = (
    "bias_temp_coeff2_dps_per_c2",
    "bias_temp_coeff3_dps_per_c3",
    "scale_temp_coeff2_per_c2",
    "scale_temp_coeff3_per_c3",
)


class ArrayValue(_Model):
    """A vector (3) or matrix (3 x 3) with its k=2 uncertainty (None where not fitted)."""

    value: list[float] | list[list[float]]
    uncertainty_k2: list[float | None] | list[list[float | None]]


class CalibrationThreeAxis(_Model):
    """record.json's `calibration_three_axis` block (a three-axis part's fit and programming;
    procedures/steps/three_axis_fit.py writes it, single-axis records never have it)."""

    axes: int = 3  # fields in the order the fit writes them (record.json as format 1)
    bias_dps: ArrayValue
    bias_temp_coeff_dps_per_c: ArrayValue
    bias_supply_coeff_dps_per_v: ArrayValue
    scale_temp_coeff_per_c: ArrayValue
    scale_supply_coeff_per_v: ArrayValue
    matrix: ArrayValue
    g_sensitivity_dps_per_mps2: ArrayValue
    reference_temperature_c: float = 25.0
    reference_supply_v: float = 5.0
    temp_supply_fitted: bool = False
    mean_die_temperature_c: float | None = None
    mean_supply_v: float | None = None
    fit_chi2: float | None = None
    fit_dof: int | None = None
    readback_ok: bool | None = None
    readback: dict[str, Any] | None = None

    @model_serializer(mode="wrap")
    def _as_written(self, handler: SerializerFunctionWrapHandler) -> Any:
        """The keys the fit (and the read-back) set, as format 1 wrote them."""
        data = handler(self)
        keep = self.model_fields_set | set(self.model_extra or {})
        return {k: v for k, v in data.items() if k in keep} if isinstance(data, dict) else data


def three_axis_block(record: RunRecord) -> CalibrationThreeAxis | None:
    """The record's three-axis calibration; None for a single-axis record."""
    return record.calibration_three_axis


def _higher_order_ok(cal: dict[str, Any]) -> dict[str, Any]:
    """A format-1 calibration without the higher-order terms that do not parse (the
    certificate showed them as not programmed)."""
    out = dict(cal)
    for key in HIGHER_ORDER_TERMS:
        if key in out:
            try:
                Coefficient.model_validate(out[key])
            except ValueError:
                log.warning("format-1 record: calibration.%s does not parse; dropped", key)
                out.pop(key)
    return out


def _three_axis_ok(block: Any) -> bool:
    try:
        CalibrationThreeAxis.model_validate(block)
    except ValueError:
        log.warning("format-1 record: calibration_three_axis does not parse; dropped")
        return False
    return True


class ConditionRecord(_Model):
    name: str  # e.g. "T25_V4.75"
    temperature_c: float
    supply_v: float
    die_temperature_c: float | None = None
    time_to_stability_s: float | None = None
    stable: bool | None = None
    bias_dps: float | None = None
    bias_uncertainty_dps: float | None = None
    scale_table: float | None = None
    scale_table_uncertainty: float | None = None
    scale_stop: float | None = None
    scale_stop_uncertainty: float | None = None
    supply_current_a: float | None = None
    supply_measured_v: float | None = None  # what the supply read back at this condition


class Event(_Model):
    time_utc: str
    station_time_s: float
    level: str = "INFO"
    step: str = ""
    message: str


class ReferenceStandard(_Model):
    """An instrument used as a reference, as station.yaml gave it when the run ended."""

    role: str  # rate_table, chamber, supply, fixture
    calibration_certificate: str = ""  # the instrument's own calibration certificate number
    reference_uncertainty: str = ""  # e.g. "0.005 % of rate (k = 2)"
    calibration_due: str | None = None


class CertificateContext(_Model):
    """What a certificate states besides the results: decision rule, standards, ambient."""

    decision_rule: str = ""  # simple | guard_banded ('' when not recorded)
    reference_standards: list[ReferenceStandard] = Field(default_factory=list)
    ambient_temperature_c: float | None = None
    ambient_humidity_pct: float | None = None
    ambient_source: str = ""  # where the ambient figures came from


class RunRecord(_Model):
    """Everything the station knows about one part's run."""

    format: str = RECORD_FORMAT
    run_id: str
    verdict: Verdict
    reason: str = ""
    failed_measurements: list[str] = Field(default_factory=list)
    simulated: bool = False
    # the effects (catalog and library ids) a simulated part was declared to carry: a model's
    # twin (`station discrepancy --simulate`); never set for any other part
    simulated_part_effects: list[str] | None = Field(
        default=None, exclude_if=lambda v: v is None
    )
    started_utc: str
    finished_utc: str | None = None
    station_local_tz: str = ""
    station: dict[str, Any] = Field(default_factory=dict)  # id, name, location, host
    operator: str = ""
    work_order: str = ""  # entered by the operator (or --work-order); empty when none
    lot: str = ""  # the production lot the part belongs to (or --lot); empty when none
    software_version: str = ""
    dut: Dut
    product: FileRef
    procedure: FileRef
    station_config: FileRef | None = None
    instruments: list[InstrumentRecord] = Field(default_factory=list)
    raw_data: FileRef | None = None
    conditions: list[ConditionRecord] = Field(default_factory=list)
    measurements: list[Measurement] = Field(default_factory=list)
    calibration: Calibration | None = None
    verification: Verification | None = None
    timings: dict[str, float] = Field(default_factory=dict)  # step name -> station seconds
    events: list[Event] = Field(default_factory=list)
    analysis: Analysis = Field(default_factory=Analysis)  # per-step analysis summaries
    certificate_number: str = ""  # station id + sequence, given when the certificate is issued
    certificate_context: CertificateContext | None = None  # filled when the run ends
    # a three-axis part's fit and programming (step program_three_axis); never single-axis
    calibration_three_axis: CalibrationThreeAxis | None = Field(
        default=None, exclude_if=lambda v: v is None
    )

    @model_validator(mode="before")
    @classmethod
    def _from_format_1(cls, data: Any) -> Any:
        """A format-1 record (free analysis and verification dicts) read as format 2; the
        file is never rewritten by reading it (signed manifests cover its bytes)."""
        if not isinstance(data, dict) or data.get("format") != RECORD_FORMAT_1:
            return data
        data = dict(data)
        data["analysis"] = analysis_from_format_1(data.get("analysis"))
        data["verification"] = verification_from_format_1(data.get("verification"))
        block = data.get("calibration_three_axis")
        if block is not None and not _three_axis_ok(block):
            data.pop("calibration_three_axis")
        if isinstance(data.get("calibration"), dict):
            data["calibration"] = _higher_order_ok(data["calibration"])
        return data




def new_file_mode() -> int:
    """The mode an ordinary new file gets under the current umask (0644 under umask 022).

    `tempfile.mkstemp` creates files 0600 whatever the umask; files renamed into a run folder
    get this mode instead, so other accounts (quality review) read them as they read raw.h5.
    """
    try:  # Linux: read the umask without changing it (os.umask is process-wide)
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return 0o666 & ~int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


def write_record(folder: Path, record: RunRecord) -> Path:
    """Write record.json atomically (temp file + rename), so a crash never leaves half a file.
    A folder that cannot be written raises StorageError naming record.json."""
    target = folder / RECORD_FILE
    text = record.model_dump_json(indent=2)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        _write_atomic(folder, target, text)
    except OSError as exc:
        raise storage_error(target, exc) from exc
    return target


def _write_atomic(folder: Path, target: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(prefix=".record-", suffix=".json", dir=folder)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            os.fchmod(fh.fileno(), new_file_mode())
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


FALLBACK_FOLDER = Path(tempfile.gettempdir()) / "gyrocal-unsaved-records"


def save_record_anywhere(folder: Path, record: RunRecord) -> Path | None:
    """record.json in its run folder; if that folder cannot be written, `<run id>.json` in
    FALLBACK_FOLDER (docs/safety.md); None if neither can be written (the caller then logs
    the verdict). Never raises an OSError: the run's end must not be lost over a disk."""
    try:
        return write_record(folder, record)
    except OSError as exc:
        first = exc
    try:
        FALLBACK_FOLDER.mkdir(parents=True, exist_ok=True)
        target = FALLBACK_FOLDER / f"{record.run_id}.json"
        _write_atomic(FALLBACK_FOLDER, target, record.model_dump_json(indent=2))
    except OSError as exc:
        log.error("%s; the record could not be kept in %s either (%s): %s %s",
                  first, FALLBACK_FOLDER, exc.strerror or exc, record.verdict, record.reason)
        return None
    log.error("%s; the record was written to %s instead", first, target)
    return target


def read_record(folder: Path) -> RunRecord:
    """Read and validate record.json; raises ValueError naming the file if it is not valid."""
    path = folder / RECORD_FILE
    try:
        with path.open("rb") as fh:  # bounded: a record is tens of kB
            raw = fh.read(MAX_RECORD_BYTES + 1)
        if len(raw) > MAX_RECORD_BYTES:
            raise ValueError(f"{path}: larger than {MAX_RECORD_BYTES // 2**20} MB; a run record "
                             "is tens of kB: not a record the station wrote")
        data = json.loads(raw.decode("utf-8"))
    except FileNotFoundError as exc:
        raise ValueError(f"{path}: no record.json in this run folder") from exc
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno})") from exc
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    except OSError as exc:
        raise ValueError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    try:
        return RunRecord.model_validate(data)
    except Exception as exc:  # pydantic.ValidationError, shown in full
        raise ValueError(f"{path}: not a valid run record: {exc}") from exc
