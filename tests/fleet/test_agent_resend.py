"""A lockstep vehicle agent learns its re-send timeout from how long its epochs take to answer.

tests/fleet/test_resend_timer.py checks the timer alone and tests/fleet/test_loadgen.py the load
generator's use of it; this checks `VehicleAgent.wait_for_solution` itself. Its bus side is a fake
node that answers each epoch a fixed delay after the agent starts waiting, longer than `resend_s`:
the first epochs are re-sent while the agent still uses `resend_s`, the later ones are not,
because by then the agent waits as long as its answers take.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from coplane.bus import Payload, decode, encode
from coplane.evaluate.runner import run_method
from coplane.messages import SolutionMessage
from coplane.recording.reader import open_recording
from coplane.sim.generate import simulate
from coplane.steps import gps_time
from coplane.vehicle_agent.agent import VehicleAgent
from coplane.vehicle_agent.settings import AgentSettings

RESEND_S = 0.1
DELAY_S = 0.35  # each epoch's answer comes this long after the agent starts waiting for it


class SlowServer:
    """A bus node whose only traffic is one solution per epoch, `DELAY_S` after the wait began."""

    def __init__(self, key: str, solution: bytes) -> None:
        self.key, self.solution = key, solution
        self.start = time.monotonic()
        self.puts: list[str] = []

    def get(self, timeout: float) -> Payload | None:
        left = self.start + DELAY_S - time.monotonic()
        if left > timeout:
            time.sleep(timeout)
            return None
        time.sleep(max(left, 0.0))
        self.start = float("inf")  # answered once
        return Payload(self.key, self.solution)

    def put(self, key: str, payload: bytes) -> None:
        self.puts.append(key)


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[bytes]]:
    rec = simulate("urban-loop", tmp_path_factory.mktemp("rec") / "r", vehicles=2, duration_s=8, seed=5)
    sols: list[bytes] = []
    run_method(open_recording(rec), "pc", on_solution=lambda s, _m: sols.append(encode(s)), jobs=1)
    return rec, sols


def test_agent_stops_resending_once_it_knows_how_long_answers_take(
    recording: tuple[Path, list[bytes]],
) -> None:
    rec, sols = recording
    agent = VehicleAgent(AgentSettings(recording=rec, vehicle_id="u1", method="pc", resend_s=RESEND_S))
    resent_per_epoch: list[int] = []
    for data in sols[:6]:
        t = gps_time(decode(SolutionMessage, data).epoch)
        node = SlowServer(agent.keys.solution, data)
        before = agent.resent
        assert agent.wait_for_solution(t, node, ["node-key"], b"node message") is None
        assert agent.resent - before == len(node.puts)  # each re-send counted, one key each
        resent_per_epoch.append(len(node.puts))
    assert resent_per_epoch[0] >= 2  # 0.35 s unanswered at a 0.1-s timeout
    assert resent_per_epoch[-3:] == [0, 0, 0]  # learnt: it waits as long as the answers take
    srtt = agent.resend.srtt_s
    assert srtt is not None and DELAY_S <= srtt < 2.0  # a busy host's answers may come later
    assert agent.resend.timeout_s() > DELAY_S
