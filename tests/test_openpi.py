"""openpi adapter against the real openpi-server package on loopback, serving a policy of our own.

The served policy is the scripted arm program re-expressed as a foreign robot would have been
trained: its own joint order, degrees and millimetres, a flipped elbow. The conversion on the
server side is written out by hand here, independent of the ActionMap it tests.
"""

import asyncio
import contextlib
import socket
import threading
import time

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("websockets")
pytest.importorskip("msgpack")
server_module = pytest.importorskip("openpi_server.websocket_policy_server")
openpi_msgpack = pytest.importorskip("openpi_client.msgpack_numpy")

from foreign_arm import FOREIGN_NAMES, MAP, assert_ran_inside_the_limits, from_foreign, to_foreign  # noqa: E402

from cellguard.errors import ConfigError  # noqa: E402
from cellguard.policy.adapter import InferenceError  # noqa: E402
from cellguard.policy.openpi import make_openpi_policy  # noqa: E402
from cellguard.policy.scripted_arm import ScriptedArmPolicy  # noqa: E402
from cellguard.policy.wire import WireError, packb, unpackb  # noqa: E402
from cellguard.robot.arm_cell import ArmPickPlace  # noqa: E402
from cellguard.robot.state import Observation  # noqa: E402
from cellguard.runtime import Run  # noqa: E402
from cellguard.scenario import parse_scenario  # noqa: E402

class ForeignScriptedPolicy:
    """An openpi ``BasePolicy``: observation dict in, ``{"actions": (H, 6)}`` in foreign units out."""

    def __init__(self, delay_s: float = 0.0):
        cell = ArmPickPlace()
        self.scripted = ScriptedArmPolicy(horizon=10, calibration=cell.context())
        self.delay_s = delay_s
        self.calls = 0

    def infer(self, obs: dict) -> dict:
        self.calls += 1
        if self.calls == 1 and self.delay_s:
            time.sleep(self.delay_s)
        t_ns = round(float(obs["observation/time_s"][0]) * 1e9)
        if t_ns == 0:
            self.scripted.reset()
        q = from_foreign(obs["observation/state"])
        seen = {k.removeprefix("observation/"): np.asarray(v, np.float64) for k, v in obs.items()
                if k.startswith("observation/") and k not in ("observation/state", "observation/time_s")}
        chunk = self.scripted.infer(Observation(t_ns, q, np.zeros(6), seen))
        return {"actions": to_foreign(chunk.actions), "policy_timing": {"infer_ms": 0.0}}

    def reset(self) -> None:
        pass


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def serve(policy, metadata: dict):
    """The real openpi WebsocketPolicyServer on 127.0.0.1, on its own thread; stopped on exit."""
    port = _free_port()
    server = server_module.WebsocketPolicyServer(policy, host="127.0.0.1", port=port, metadata=metadata)
    loop = asyncio.new_event_loop()
    task = loop.create_task(server.run())
    thread = threading.Thread(target=lambda: loop.run_until_complete(asyncio.gather(task, return_exceptions=True)),
                              daemon=True)
    thread.start()
    for _ in range(200):  # bounded wait for the port to accept
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), timeout=0.1):
            break
        time.sleep(0.025)
    try:
        yield f"ws://127.0.0.1:{port}"
    finally:
        loop.call_soon_threadsafe(task.cancel)
        thread.join(5)
        loop.close()


@pytest.fixture(scope="module")
def map_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("maps") / "foreign.yaml"
    path.write_text(yaml.safe_dump(MAP))
    return path


@pytest.fixture(scope="module")
def foreign_server():
    with serve(ForeignScriptedPolicy(), {"action_names": FOREIGN_NAMES, "dt_s": 0.02}) as uri:
        yield uri


def test_wire_format_matches_openpi_client_both_ways():
    doc = {"observation/state": np.arange(6, dtype=np.float32), "prompt": "pick", "n": np.int64(3)}
    theirs = openpi_msgpack.unpackb(packb(doc))
    np.testing.assert_array_equal(theirs["observation/state"], doc["observation/state"])
    assert theirs["prompt"] == "pick" and theirs["n"] == 3
    ours = unpackb(openpi_msgpack.packb({"actions": np.ones((4, 2), np.float64)}))
    assert ours["actions"].shape == (4, 2) and ours["actions"].flags.writeable


def test_wire_refuses_object_arrays_and_garbage():
    with pytest.raises(WireError, match="not allowed"):
        packb({"a": np.array([object()], dtype=object)})
    import msgpack

    pickled = msgpack.packb({b"__ndarray__": True, b"data": b"\x80\x04K\x01.", b"dtype": "|O", b"shape": [1]})
    with pytest.raises(WireError, match="not allowed"):
        unpackb(pickled)
    with pytest.raises(WireError):
        unpackb(b"\xc1\xff\x00")


def test_openpi_policy_runs_the_arm_cell_through_a_foreign_action_space(foreign_server, map_file):
    scenario = parse_scenario({"cell": "arm-pick-place", "seed": 3, "acceptance_cycles": 2, "production_cycles": 0,
                               "policy": f"openpi:{foreign_server}?map={map_file}&timeout=5"})
    run = Run(scenario)
    outcomes = [run.cycle() for _ in range(2)]
    assert_ran_inside_the_limits(run, outcomes)
    run.policy.close()


def test_a_wrong_map_is_refused_before_anything_runs(foreign_server, tmp_path):
    bad = {**MAP, "actions": MAP["actions"][1:] + MAP["actions"][:1]}  # order differs from the server's names
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(bad))
    with pytest.raises(ConfigError, match=r"actions\[0\].name is 'wrist_roll.deg' but openpi:ws://"):
        make_openpi_policy(f"{foreign_server}?map={path}", ArmPickPlace())


def test_receive_timeout_then_reconnect(map_file):
    with serve(ForeignScriptedPolicy(delay_s=0.6), {"action_names": FOREIGN_NAMES}) as uri:
        cell = ArmPickPlace()
        cell.begin_cycle(0)
        policy = make_openpi_policy(f"{uri}?map={map_file}&timeout=0.15&retries=1&dt=0.02", cell)
        with pytest.raises(InferenceError, match="no reply within 0.15 s|cannot connect"):
            policy.infer(cell.observe())
        time.sleep(0.8)  # the server finishes its slow call and drops the closed connection
        chunk = policy.infer(cell.observe())
        assert chunk.actions.shape == (10, 6) and policy.backend.reconnects >= 1
        policy.close()


def test_api_key_header_is_sent_and_server_errors_surface(map_file, monkeypatch):
    seen = []
    original = server_module._health_check

    def recording(connection, request):
        seen.append(request.headers.get("Authorization"))
        return original(connection, request)

    monkeypatch.setattr(server_module, "_health_check", recording)
    monkeypatch.setenv("CELLGUARD_TEST_KEY", "s3cret")

    class Failing(ForeignScriptedPolicy):
        def infer(self, obs):
            raise RuntimeError("model exploded")

    with serve(Failing(), {"action_names": FOREIGN_NAMES}) as uri:
        cell = ArmPickPlace()
        policy = make_openpi_policy(f"{uri}?map={map_file}&api_key_env=CELLGUARD_TEST_KEY&retries=0&dt=0.02", cell)
        assert seen[-1] == "Api-Key s3cret"
        with pytest.raises(InferenceError, match="server error: RuntimeError: model exploded"):
            policy.infer(cell.observe())
        policy.close()


def test_unset_api_key_variable_is_a_config_error(foreign_server, map_file):
    with pytest.raises(ConfigError, match="api_key_env: environment variable 'NO_SUCH_VAR_X' is not set"):
        make_openpi_policy(f"{foreign_server}?map={map_file}&api_key_env=NO_SUCH_VAR_X", ArmPickPlace())


@pytest.mark.parametrize("metadata, why", [({"dt_s": 0.02}, "gives no action_dim or action_names"),
                                           ({"action_dim": 10**12}, "action_dim 1000000000000 is not an integer"),
                                           ({"action_dim": "6"}, "action_dim '6' is not an integer")])
def test_metadata_without_a_usable_action_dim_says_which(metadata, why, map_file):
    with serve(ForeignScriptedPolicy(), metadata) as uri, pytest.raises(ConfigError, match=why):
        make_openpi_policy(f"{uri}?map={map_file}", ArmPickPlace())


@pytest.mark.parametrize("address, why", [
    ("ws://[::1", r"not a valid address \(Invalid IPv6 URL\)"),
    ("ws://127.0.0.1:99999", r"not a valid address \(Port out of range"),
    ("ws://127.0.0.1:port", r"not a valid address \(Port could not be cast"),
    ("ws://:8000", r"not a valid address \(hostname isn't provided\)"),
    ("ws://127.0.0.1:0", "port 0 cannot be connected to"),
])
def test_a_malformed_address_is_refused_in_one_line_before_connecting(address, why):
    """urllib's ValueError escaped _connect as a traceback (exit 1); port 0 silently became 80."""
    with pytest.raises(ConfigError, match=why) as caught:
        make_openpi_policy(f"{address}?timeout=0.1", ArmPickPlace())
    assert "\n" not in str(caught.value)


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=40))
def test_any_address_is_either_accepted_or_refused_with_a_config_error(tail):
    from cellguard.policy.openpi import check_address

    for address in (f"ws://{tail}", f"wss://127.0.0.1:{tail}", f"ws://[{tail}"):
        with contextlib.suppress(ConfigError):
            check_address(address)


def test_a_reply_over_the_message_limit_names_the_limit_and_close_code_1009(map_file):
    """It read as "connection lost (ConnectionClosedError)", with nothing saying the reply was too big."""

    class Huge(ForeignScriptedPolicy):
        def infer(self, obs):
            reply = super().infer(obs)
            return {**reply, "actions": np.repeat(reply["actions"], 20000, axis=0)}  # 200000 x 6 float64: 9.6 MB

    with serve(Huge(), {"action_names": FOREIGN_NAMES}) as uri:
        cell = ArmPickPlace()
        policy = make_openpi_policy(f"{uri}?map={map_file}&retries=0&timeout=5&dt=0.02", cell)
        with pytest.raises(InferenceError, match=r"reply over the limit of 8388608 bytes \(8 MiB\); closed with 1009 "
                                                 r"\(message too big\)"):
            policy.infer(cell.observe())
        policy.close()


@pytest.mark.parametrize("dt", ["0", "nan", "2", "abc"])
def test_a_bad_dt_is_named_before_connecting(dt):
    """With the server down, ?dt=0 said 'cannot connect (ConnectionRefusedError)': the period's own fault hidden."""
    with pytest.raises(ConfigError, match=r"^policy: openpi: option dt"):
        make_openpi_policy(f"openpi:ws://127.0.0.1:{_free_port()}?dt={dt}", ArmPickPlace())
