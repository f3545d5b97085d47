"""The ACUTROL twin on the wire, with a plain TCP client: reply forms, abbreviations, one
world time per line, error replies, world faults in the status word, drop/restore/delay."""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator

import pytest

from drivers.acutrol_codes import Err, StatusBit
from drivers.rate_table_map import Fault
from drivers.sim.acutrol_twin import AcutrolTwin
from tests.drivers._twin_thread import TwinThread


class Client:
    def __init__(self, endpoint: str) -> None:
        host, _, port = endpoint.rpartition(":")
        self.sock = socket.create_connection((host, int(port)), timeout=2.0)
        self.rx = b""

    def ask(self, line: str) -> str:
        self.sock.sendall(line.encode() + b"\r\n")
        while b"\r\n" not in self.rx:
            chunk = self.sock.recv(4096)
            if not chunk:
                raise ConnectionError("closed")
            self.rx += chunk
        reply, _, self.rx = self.rx.partition(b"\r\n")
        return reply.decode()

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def twin() -> Iterator[TwinThread]:
    with TwinThread(AcutrolTwin, speed=100.0) as tt:
        yield tt


@pytest.fixture
def client(twin: TwinThread) -> Iterator[Client]:
    c = Client(twin.twin.endpoint())
    yield c
    c.close()


def status(client: Client) -> StatusBit:
    return StatusBit(int(client.ask(":status? 1")))


def test_idn_and_ok_and_compound_query_reply_forms(client: Client, twin: TwinThread):
    maker, model, serial, firmware = client.ask("*IDN?").split(",")
    assert maker == "Acutronic" and model == twin.world.table.cfg.model
    assert client.ask(":interlock:close 1") == "OK"
    assert client.ask(":interlock? 1") == "Closed"
    values = client.ask(":read:pos? 1;rate? 1;:status? 1;:fault? 1;:system:time?").split(";")
    assert len(values) == 5
    assert StatusBit(int(values[2])) & StatusBit.CLOSED and values[3] == "0"


def test_abbreviated_headers_as_public_clients_send_them(client: Client):
    assert client.ask(":int:close 1") == "OK"
    assert client.ask(":mode:rate 1;:dem:rate 1,25") == "OK"
    assert client.ask(":mode? 1") == "Rate"
    assert float(client.ask(":lim:acc? rate,1")) > 0
    assert client.ask(":lim:acc rate,1,500") == "OK"
    assert float(client.ask(":limit:acc? rate,1")) == 500.0


def test_rate_demand_moves_the_world_table_and_position_counts_whole_encoder_steps(
    client: Client, twin: TwinThread
):
    client.ask(":interlock:close 1")
    client.ask(":limit:acc rate,1,1000;:mode:rate 1;:demand:rate 1,100")
    deadline = time.monotonic() + 5
    while not status(client) & StatusBit.AT_RATE:
        assert time.monotonic() < deadline
        time.sleep(0.005)
    pos, rate, t = (float(v) for v in client.ask(":read:pos? 1;rate? 1;:system:time?").split(";"))
    assert rate == pytest.approx(100.0, abs=0.05)
    cpr = twin.world.table.cpr
    assert pos * cpr / 360.0 == pytest.approx(round(pos * cpr / 360.0), abs=1e-3)
    assert twin.call(twin.world.truth)["table"]["mode"] == "rate"


def test_error_replies_name_code_and_reason(client: Client):
    def err(line: str) -> int:
        reply = client.ask(line)
        assert reply.startswith("ERR "), reply
        return int(reply[4:].split(",", 1)[0])

    assert err(":frobnicate 1") == Err.UNDEFINED_HEADER
    assert err(":demand:position 1,10") == Err.SETTINGS_CONFLICT  # not in position mode
    assert err(":mode:rate 1;:demand:rate 1,5000") == Err.OUT_OF_RANGE
    assert err(":limit:acc rate,1,0") == Err.OUT_OF_RANGE
    assert err(":demand:rate 1,fast") == Err.DATA_TYPE
    assert err(":mode:rate 2") == Err.OUT_OF_RANGE  # one axis only
    assert err(":mode:rate") == Err.MISSING_PARAMETER


def test_world_faults_show_in_status_fault_and_refuse_closing(client: Client, twin: TwinThread):
    client.ask(":interlock:close 1")
    twin.call(lambda: twin.world.set_interlock(True))
    assert status(client) & StatusBit.SAFETY_OPEN
    assert not status(client) & StatusBit.CLOSED
    assert client.ask(":interlock:close 1").startswith(f"ERR {int(Err.SAFETY_OPEN)},")
    twin.call(twin.world.clear_world_faults)
    twin.call(lambda: twin.world.trip_table(Fault.ESTOP))
    word = status(client)
    assert word & StatusBit.FAULT and word & StatusBit.ESTOP
    assert client.ask(":fault? 1") == "4" and client.ask(":interlock? 1") == "Fault"
    assert client.ask(":interlock:reset 1").startswith(f"ERR {int(Err.ESTOP)},")
    twin.call(twin.world.clear_world_faults)
    assert client.ask(":Interlock:Reset") == "OK"  # all axes, as public clients send it
    assert client.ask(":fault? 1") == "0"
    assert client.ask(":interlock:close 1") == "OK"


def test_drop_closes_and_refuses_then_restore_serves_on_the_same_port(
    client: Client, twin: TwinThread
):
    endpoint = twin.twin.endpoint()
    twin.run(twin.twin.drop())
    with pytest.raises(OSError):
        client.ask("*IDN?")
    with pytest.raises(OSError):
        Client(endpoint)
    twin.run(twin.twin.restore())
    assert twin.twin.endpoint() == endpoint
    again = Client(endpoint)
    assert again.ask("*IDN?").startswith("Acutronic,")
    again.close()


def test_delay_makes_every_answer_late(client: Client, twin: TwinThread):
    twin.twin.delay_s = 0.3
    t0 = time.monotonic()
    client.ask("*IDN?")
    assert time.monotonic() - t0 >= 0.3
    twin.twin.delay_s = 0.0


def test_closing_the_interlock_holds_the_axis_instead_of_resuming_an_old_demand(
    client: Client, twin: TwinThread
):
    client.ask(":interlock:close 1")
    client.ask(":limit:acc rate,1,1000;:mode:rate 1;:demand:rate 1,100")
    client.ask(":interlock:open 1")
    assert client.ask(":interlock:close 1") == "OK"
    time.sleep(0.05)
    assert float(client.ask(":read:rate? 1")) == pytest.approx(0.0, abs=0.05)
    assert client.ask(":demand:rate 1,20") == "OK"
