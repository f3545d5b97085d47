"""Every YAML example in docs/ loads with the station's own loaders; every shipped procedure
and the docs' whole procedures run on the simulated bench.

An example is a fenced `yaml` block. The doc says, in an HTML comment on the line before the
block, what it is an example of (invisible when rendered):

    <!-- doc-test: yaml-into config/station.yaml -->   a fragment of that shipped file: merged
                                                       into a copy of it, then loaded
    <!-- doc-test: yaml-whole procedure -->            a whole file of that kind
    <!-- doc-test: skip WHY -->                        not loadable here, and why

Merging: mappings merge key by key (an instrument given with its `driver:` replaces the
host's: a driver's settings are its own); a list of steps replaces the host's steps of the same
`step:` kind; anything else replaces the host's value. A fragment that no longer fits its
file (a renamed key, a value out of range) fails here with the loader's own message.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import pytest
import yaml

from drivers.servo_profile import load_profile
from drivers.sim.config import load_sim_config
from procedures.loading.config import load_procedure, load_product
from station.station_file import load_settings
from tests.journeys.doc_commands import MARKER, REPO

LOADERS = {
    "station": lambda p: load_settings(p),
    "product": load_product,
    "procedure": load_procedure,
    "sim": load_sim_config,
    "table-profile": load_profile,
}
FENCE_YAML = re.compile(r"^\s*```ya?ml\s*$")


def _examples() -> list[tuple[str, str, dict[str, str]]]:
    """(where, the block's text, its markers) for every yaml block of docs/."""
    found = []
    for path in sorted((REPO / "docs").glob("*.md")):
        lines = path.read_text(encoding="utf-8").splitlines()
        markers: dict[str, str] = {}
        i = 0
        while i < len(lines):
            marker = MARKER.search(lines[i])
            if marker:
                markers[marker.group(2)] = marker.group(3)
            elif FENCE_YAML.match(lines[i]):
                end = next(j for j in range(i + 1, len(lines)) if lines[j].strip() == "```")
                text = textwrap.dedent("\n".join(lines[i + 1:end]))
                found.append((f"{path.relative_to(REPO)}:{i + 1}", text, markers))
                markers, i = {}, end
            elif lines[i].strip():
                markers = {}
            i += 1
    return found


EXAMPLES = _examples()


def _kind(path: Path) -> str:
    rel = path.relative_to(path.parents[len(path.parents) - 1])
    text = str(rel)
    if "/sim/" in text:
        return "sim"
    if "/products/" in text:
        return "product"
    if path.name.startswith("station"):
        return "station"
    return "procedure"


def _merge(host: Any, fragment: Any) -> Any:
    if isinstance(host, dict) and isinstance(fragment, dict) and "driver" not in fragment:
        out = dict(host)
        for key, value in fragment.items():
            out[key] = _merge(host[key], value) if key in host else value
        return out
    if isinstance(fragment, list) and all(isinstance(f, dict) and "step" in f for f in fragment):
        kinds = {f["step"]: f for f in fragment}
        host_steps = host if isinstance(host, list) else []
        assert any(isinstance(h, dict) and h.get("step") in kinds for h in host_steps), (
            f"the host has no step of kind {sorted(kinds)}")
        return [kinds.get(h.get("step"), h) if isinstance(h, dict) else h for h in host_steps]
    return fragment


@pytest.fixture(scope="module")
def tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of config/ and tests/data (a fragment's host is copied, never changed)."""
    root = tmp_path_factory.mktemp("examples")
    shutil.copytree(REPO / "config", root / "config", ignore=shutil.ignore_patterns("signing"))
    shutil.copytree(REPO / "tests" / "data", root / "tests" / "data")
    return root


def _load(where: str, text: str, markers: dict[str, str], tree: Path) -> Path:
    document = yaml.safe_load(text)
    if "yaml-whole" in markers:
        kind = markers["yaml-whole"]
        host = tree / "config" / "procedures" / f"example-{where.replace('/', '_')}.yaml"
        if kind == "procedure":
            document.setdefault("product", "../products/gyr130.yaml")
    else:
        into = REPO / markers["yaml-into"]
        assert into.is_file(), f"{where}: yaml-into names {into}, which does not exist"
        host = tree / markers["yaml-into"]
        kind = _kind(host)
        document = _merge(yaml.safe_load(into.read_text(encoding="utf-8")), document)
        host = host.with_name(f"example-{host.name}")
    host.write_text(yaml.safe_dump(document, sort_keys=False), encoding="utf-8")
    LOADERS[kind](host)
    return host


@pytest.mark.parametrize("where, text, markers", EXAMPLES, ids=[e[0] for e in EXAMPLES])
def test_doc_yaml_example_loads(where: str, text: str, markers: dict[str, str],
                                tree: Path) -> None:
    if "skip" in markers:
        pytest.skip(f"{where}: {markers['skip']}")
    assert {"yaml-into", "yaml-whole"} & set(markers), (
        f"{where}: say what this example is: <!-- doc-test: yaml-into config/FILE.yaml -->, "
        f"<!-- doc-test: yaml-whole KIND --> ({', '.join(LOADERS)}) or "
        f"<!-- doc-test: skip WHY --> on the line before it")
    _load(where, text, markers, tree)


def _station_for(procedure: Path) -> list[str]:
    if "manual" in procedure.name:
        return ["--station", str(REPO / "config" / "station-manual.yaml")]
    return []


def _duts(procedure: Path) -> list[str]:
    serial = "IMU-0001" if "three-axis" in procedure.name else "SIM-0001"
    return ["--dut", serial]


PROCEDURES = sorted((REPO / "config" / "procedures").glob("*.yaml"))


@pytest.mark.station_grid
@pytest.mark.parametrize("procedure", PROCEDURES, ids=[p.name for p in PROCEDURES])
def test_every_shipped_procedure_runs_on_the_simulated_bench(procedure: Path,
                                                             tmp_path: Path) -> None:
    station = Path(sys.executable).parent / "station"
    done = subprocess.run(
        [str(station), "run", "--sim", "--procedure", str(procedure), *_station_for(procedure),
         *_duts(procedure), "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=900, cwd=REPO,
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert list(tmp_path.glob("*/certificate.pdf")), done.stdout


WHOLE_PROCEDURES = [e for e in EXAMPLES if e[2].get("yaml-whole") == "procedure"]


@pytest.mark.station_grid
@pytest.mark.parametrize("where, text, markers", WHOLE_PROCEDURES,
                         ids=[e[0] for e in WHOLE_PROCEDURES])
def test_the_docs_whole_procedures_run(where: str, text: str, markers: dict[str, str],
                                       tree: Path, tmp_path: Path) -> None:
    host = _load(where, text, markers, tree)
    station = Path(sys.executable).parent / "station"
    done = subprocess.run(
        [str(station), "run", "--sim", "--procedure", str(host), "--dut", "SIM-0001",
         "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=900, cwd=REPO,
    )
    assert done.returncode in (0, 1), done.stdout[-3000:] + done.stderr[-3000:]
    assert list(tmp_path.glob("*/certificate.pdf")), done.stdout


def test_the_docs_have_yaml_examples() -> None:
    assert len(EXAMPLES) >= 15
    assert WHOLE_PROCEDURES, "docs/procedures.md's whole procedure lost its marker"
