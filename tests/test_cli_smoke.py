import subprocess
import sys


def test_station_help_lists_usage() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "station", "--help"], capture_output=True, text=True, check=True
    )
    assert "usage: station" in out.stdout
