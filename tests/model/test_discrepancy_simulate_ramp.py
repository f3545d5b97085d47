"""`station discrepancy RUN_FOLDER --simulate` on a ramp folder of the honest thermal bench
(issue 29, deliverable 4): one part through the short ramp (tests/procedures/data/
ramp_short.yaml: 25 -> 27 -> 25 C, the table cycling 4 rates) on the default bench (element
lag, gradient bias, hysteresis, socket air), in lockstep, analysed from `first_order`.

- the ramp's plateaus are compared: the twins ramp on the measured timeline (a part alone,
  in lockstep), every ramp plateau piece is matched, the dies at the same temperature (the
  twin in the measured part's socket of the same bench: the same air);
- the twins run on a bench with the honest thermal physics off and carry the model's terms
  only, the found thermal term as a generic term; the twin run's certificate names them;
- the gap with the extended model's twin is within 1.5 x its floor, and where a term in the
  die's rate of change was named the starting model's twin is further off.

The part: SIM-2933. Over six parts alone on this ramp (benchmarks/bench_discrepancy_simulate.py
--thermal --alone --procedure tests/procedures/data/ramp_short.yaml, SIM-2931 to -2936) the
gap after was 1.70, 0.83, 0.54, 0.82, 1.01 and 1.04 x the floor; only on SIM-2933 was a
thermal term named (lib_w_dT_dTdt: rate, temperature, temperature_rate). On the others the
short ramp's 2 C cannot tell the element's lag from the alternatives ("not separable"),
nothing is named and the twin is the starting model: SIM-2931's 1.70 x is that lag left out
(the same part on the bench without the thermal physics: 1.18 x), not the twin. On this
ramp the named term is worth little (gap before 0.56 x, after 0.54 x); on eol-ramp the lag
is named on every part and halves the gap (docs/discrepancy.md). A lockstep run of one part
is deterministic, so these margins are the run's own; they move only when the bench's
noise draws do, and `before > after` is then the assertion to revisit (the extended model
holds the starting one, so its twin is rarely the further off where the term is real).

Three station runs of a few seconds each and the workflow on ~15,000 samples: station_grid.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from drivers.sim.config import load_sim_config
from drivers.sim.thermal_physics import draw_thermal
from station.cli import main as cli
from station.sim_run import run_simulated
from tests.tools import need

pytestmark = [pytest.mark.slow, pytest.mark.station_grid]

ROOT = Path(__file__).resolve().parents[2]
PROCEDURE = ROOT / "tests" / "procedures" / "data" / "ramp_short.yaml"
SERIAL = "SIM-2933"


@pytest.fixture(scope="module")
def simulated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    work = tmp_path_factory.mktemp("ramp-simulate")
    result, _ = run_simulated([{"socket": 1, "serial": SERIAL}], procedure_path=PROCEDURE,
                              out=work / "measured", speed=None)  # the honest default bench
    assert str(result.verdicts[1]) in ("PASS", "FAIL"), result.reasons
    out = work / "disc"
    code = cli.main(["discrepancy", str(result.folders[1]), "--model", "first_order",
                     "--simulate", "--out", str(out)])
    assert code == 0
    return out, json.loads((out / "discrepancy.json").read_text())


def test_ramp_plateaus_are_compared_on_the_measured_timeline(simulated: tuple[Path, dict]
                                                             ) -> None:
    _, res = simulated
    ramp = [w for w in res["simulation_windows"] if w["kind"] == "ramp_plateau"]
    assert len(ramp) >= 40  # the short ramp: ~50 plateaus of 2 s, heating and cooling
    assert res["simulation_windows_compared"] == res["simulation_windows_measured"]
    assert max(abs(w["die_temp_c"] - w["twin_die_temp_c"]) for w in ramp) < 0.05
    assert res["simulation_air_given_c"] == {}  # the default bench's air is the measured one's


def test_the_twin_carries_the_model_s_terms_only_and_its_certificate_says_which(
    simulated: tuple[Path, dict]
) -> None:
    out, res = simulated
    after = load_sim_config(out / "twin_after.yaml")
    assert draw_thermal(SERIAL, after.part_physics.thermal).ideal  # no lag, gradient, hysteresis
    generic = {e for e in res["effects_added"] if e.startswith("lib_")}
    assert generic <= set(after.parts[0].effects)
    need("pdftotext")
    cert = Path(res["simulation_twin_after"]["run_folder"]) / "certificate.pdf"
    page1 = " ".join(subprocess.run(["pdftotext", "-f", "1", "-l", "1", str(cert), "-"],
                                    capture_output=True, text=True, check=True).stdout.split())
    carried = ", ".join(res["final_model"]["effects"])
    assert f"Simulated part a model's twin; effects it carries: {carried}" in page1


def test_the_extended_twin_reproduces_the_ramp_within_1_5_x_the_floor(
    simulated: tuple[Path, dict]
) -> None:
    _, res = simulated
    before, after = res["simulation_gap_before_dps"], res["simulation_gap_after_dps"]
    floor = res["simulation_noise_floor_dps"]
    assert after <= 1.5 * floor, (before, after, floor)
    rate_terms = [it for it in res["iterations"] if "temperature_rate" in it["regressors"]]
    if rate_terms:
        assert before > after, (before, after, floor)
