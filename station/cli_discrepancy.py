"""`station discrepancy DATA [--model base|first_order|PATH] [--dut SERIAL] [--json PATH]
[--out DIR]`: find where the gyro model and a run's data disagree and name the effect."""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path
from typing import TYPE_CHECKING

from station.errors import UserError

if TYPE_CHECKING:
    from procedures.model.discrepancy import DiscrepancyResult

log = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "discrepancy",
        help="find where the model and the data disagree and name the effect",
        description=(
            "Fit the gyro model to a run (a run folder or a CSV with columns time_s, gyro_dps, "
            "ref_rate_dps, ref_angle_deg, temp_c, supply_v), find where the residuals exceed "
            "the noise floor, name the catalog effect that explains it, add it, refit and "
            "repeat. Writes discrepancy.json, the extended model YAML and a PDF report."
        ),
    )
    p.add_argument("data", type=Path, help="run folder (record.json + raw.h5) or CSV file")
    p.add_argument(
        "--model",
        default="base",
        help="starting model: base, first_order or a model YAML file (default base)",
    )
    p.add_argument("--dut", help="serial of the part, to pick or check the run folder")
    p.add_argument("--json", type=Path, help="write the JSON result here (default OUT/...)")
    p.add_argument("--out", type=Path, help="folder for the report, model and JSON")
    p.add_argument(
        "--alpha",
        type=float,
        default=None,
        help="family-wise false-alarm rate per iteration (default 0.01)",
    )
    p.set_defaults(handler=handler)


def handler(args: argparse.Namespace) -> int:
    from procedures.model.discrepancy import DEFAULT_ALPHA, run_discrepancy
    from procedures.model.model_io import load_model, save_model
    from procedures.model.output import result_to_json
    from procedures.model.run_folder import load_data

    alpha = DEFAULT_ALPHA if args.alpha is None else args.alpha
    if not 0 < alpha < 0.5:
        raise UserError(f"--alpha {alpha} is out of range; give a rate between 0 and 0.5")
    try:
        model = load_model(args.model)
    except ValueError as exc:
        raise UserError(str(exc)) from exc
    try:
        traj = load_data(args.data, dut=args.dut)
    except ValueError as exc:
        raise UserError(str(exc)) from exc
    try:
        result = run_discrepancy(traj, model, alpha=alpha)
    except ValueError as exc:
        raise UserError(f"{args.data}: {exc}") from exc
    out = args.out or (args.data if args.data.is_dir() else args.data.parent) / "discrepancy"
    out.mkdir(parents=True, exist_ok=True)
    model_path = save_model(result.final_model, out / "model.yaml")
    payload = result_to_json(result)
    payload["model_path"] = str(model_path)
    payload["data"] = str(args.data)
    report_path = out / "discrepancy_report.pdf"
    try:
        from reports.discrepancy_report import write_report

        write_report(result, report_path, title_data=str(args.data))
        payload["report_path"] = str(report_path)
    except Exception as exc:  # the JSON and model are still useful without the PDF
        log.exception("discrepancy report failed")
        payload["report_error"] = str(exc)
    json_path = args.json or out / "discrepancy.json"
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(payload, indent=2), encoding="utf-8")
    _print_summary(result, json_path, model_path, payload.get("report_path"))
    return 0


def _print_summary(
    result: DiscrepancyResult, json_path: Path, model_path: Path, report: str | None
) -> None:
    print(
        f"gap {result.gap_initial_dps:.4g} deg/s at start, noise floor "
        f"{result.noise_floor_dps:.4g} deg/s"
    )
    for it in result.iterations:
        print(
            f"named {it.effect}: gap {it.gap_before_dps:.4g} -> {it.gap_after_dps:.4g} deg/s "
            f"(p_holm {it.evidence['p_holm']:.2g})"
        )
    for ns in result.not_separable:
        print(f"not separable: {' / '.join(ns['effects'])} (nothing added)")
    if not result.iterations and not result.not_separable:
        print("nothing named: no candidate effect is significant")
    ratio = result.gap_final_dps / result.noise_floor_dps
    print(f"gap {result.gap_final_dps:.4g} deg/s at end ({ratio:.2f} x floor)")
    print(f"json: {json_path}")
    print(f"model: {model_path}")
    if report:
        print(f"report: {report}")
