"""A part's run folder as a run starts: its first record.json (RUNNING: the station, the
people, the procedure, product and station files) and its raw-data writer."""

from __future__ import annotations

import datetime as dt
import socket as socketlib
from pathlib import Path
from typing import Protocol

from common.yaml_input import LoadedYaml
from procedures.loading.config import ProcedureConfig, ProductConfig
from procedures.runtime.rawdata import RawDataWriter
from procedures.runtime.record import RAW_DATA_FILE, Dut, FileRef, RunRecord, Verdict, write_record
from procedures.runtime.run_parts import PartRun
from station import __version__
from station.endpoints import Endpoints
from station.run_folder import create_run_folder
from station.settings import LoadedSettings


class PartSource(Protocol):
    """What a part's record names: the station, the people, the procedure and the product
    (a UutRunner has all of it)."""

    settings: LoadedSettings
    out: Path
    endpoints: Endpoints | None
    operator: str
    work_order: str
    lot: str
    procedure: ProcedureConfig
    procedure_path: Path
    procedure_file: LoadedYaml
    product: ProductConfig
    product_path: Path
    product_file: LoadedYaml


def _declared_effects(endpoints: Endpoints | None, sock: int) -> list[str] | None:
    """The effects the simulated part in `sock` was declared to carry (a model's twin)."""
    if endpoints is None or sock not in endpoints.part_effects:
        return None
    return list(endpoints.part_effects[sock])


def new_part(run: PartSource, sock: int, serial: str, counts_per_rev: int | None) -> PartRun:
    """A part's run folder with its first record.json (RUNNING) and its raw-data writer."""
    folder = create_run_folder(run.out, serial)
    info = run.settings.settings.station
    now = dt.datetime.now(dt.UTC)
    record = RunRecord(
        run_id=folder.name,
        verdict=Verdict.RUNNING,
        simulated=run.endpoints is not None,
        simulated_part_effects=_declared_effects(run.endpoints, sock),
        started_utc=now.isoformat(timespec="milliseconds"),
        station_local_tz=str(dt.datetime.now().astimezone().tzinfo),
        station={
            "id": info.id,
            "name": info.name,
            "location": info.location,
            "host": socketlib.gethostname(),
        },
        operator=run.operator,
        work_order=run.work_order,
        lot=run.lot,
        software_version=__version__,
        dut=Dut(serial=serial, socket=sock, product=run.product.product),
        product=FileRef(
            path=str(run.product_path),
            name=run.product.product,
            version=run.product.part_number,
            sha256=run.product_file.sha256,
        ),
        procedure=FileRef(
            path=str(run.procedure_path),
            name=run.procedure.name,
            version=run.procedure.version,
            sha256=run.procedure_file.sha256,
        ),
        station_config=FileRef(
            path=str(run.settings.source.path),
            name=info.id,
            sha256=run.settings.source.sha256,
        ),
        raw_data=FileRef(path=RAW_DATA_FILE, name="raw data (HDF5)", sha256=""),
    )
    write_record(folder, record)
    writer = RawDataWriter(
        folder / RAW_DATA_FILE,
        {
            "serial": serial,
            "run_id": folder.name,
            "socket": sock,
            "procedure": run.procedure.name,
            "product": run.product.product,
            "station": info.id,
            "simulated": run.endpoints is not None,
            "software_version": __version__,
            "time_base": "fixture clock (s); station_time_s: station clock estimate",
            # scales /samples/encoder_counts (the fixture latches the table's encoder);
            # the table driver says how many counts it has per turn
            **({"encoder_counts_per_rev": counts_per_rev} if counts_per_rev else {}),
            **({"axes": 3} if run.product.axes == 3 else {}),
        },
        extra_groups=("samples_xyz",) if run.product.axes == 3 else (),
    )
    return PartRun(socket=sock, serial=serial, folder=folder, record=record, writer=writer)
