"""Every Zenoh session this project opens has multicast scouting off: the integration tests (and users' runs on a
lab network) must never discover a developer's LAN or a real robot's router."""

from __future__ import annotations

import json
import re
import socket
from pathlib import Path

import pytest
import zenoh

from cso_runtime import status, transport
from cso_runtime.transport import TransportConfig, loopback_endpoint, zenoh_config

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("conf", [
    TransportConfig(mode="peer"),
    TransportConfig(mode="client", connect=[loopback_endpoint(7447)]),
    TransportConfig(mode="router", listen=[loopback_endpoint(0)]),
], ids=["peer", "client", "router"])
def test_every_mode_has_multicast_scouting_off(conf):
    cfg = zenoh_config(conf)
    assert cfg.get_json("scouting/multicast/enabled") == "false"
    assert json.loads(cfg.get_json("mode")) == conf.mode


def test_the_sessions_opened_by_services_and_by_status_have_scouting_off(monkeypatch):
    opened: list[zenoh.Config] = []

    def fake_open(cfg):
        opened.append(cfg)
        raise zenoh.ZError("not opened in this test")

    monkeypatch.setattr(zenoh, "open", fake_open)
    with pytest.raises(transport.TransportError):
        transport.open_session(TransportConfig(mode="peer"))
    assert status.query_status([loopback_endpoint(7447)], "r0") is None
    assert len(opened) == 2
    assert [cfg.get_json("scouting/multicast/enabled") for cfg in opened] == ["false", "false"]


def test_no_other_code_opens_a_zenoh_session():
    """The two sessions above are the only ones: a new ``zenoh.open`` elsewhere would bypass ``zenoh_config``."""
    sites = sorted(
        str(path.relative_to(ROOT))
        for folder in ("cso_runtime", "services", "robot_sim", "benchmarks")
        for path in (ROOT / folder).rglob("*.py")
        if re.search(r"zenoh\.open\(", path.read_text(encoding="utf-8"))
    )
    assert sites == ["cso_runtime/status.py", "cso_runtime/transport.py"]


def test_the_embedded_router_picks_another_port_when_its_first_is_taken(monkeypatch):
    """``free_tcp_port`` frees the port it found before Zenoh binds it; another process may take it then (two
    picks in a row returned the same port 4 times in 20,000). ``up`` then picks again instead of exiting 3."""
    taken = socket.socket()
    taken.bind(("127.0.0.1", 0))
    taken.listen(1)
    free = transport.free_tcp_port
    picks = iter([taken.getsockname()[1]])
    monkeypatch.setattr(transport, "free_tcp_port", lambda host="127.0.0.1": next(picks, None) or free(host))
    try:
        session, endpoints = transport.open_router(["tcp/127.0.0.1:0"], [])
        with session:
            assert endpoints != [loopback_endpoint(taken.getsockname()[1])]
            assert endpoints[0].startswith("tcp/127.0.0.1:") and not endpoints[0].endswith(":0")
        with pytest.raises(transport.TransportError) as err:  # a port the profile names is not changed: a clear error
            transport.open_router([loopback_endpoint(taken.getsockname()[1])], [])
        assert err.value.cause == transport.LISTEN_IN_USE
    finally:
        taken.close()


def test_an_embedded_router_that_cannot_reach_a_router_to_join_fails_to_open():
    """``up --connect tcp/HOST:PORT`` with nothing there started the run anyway (exit 0), the router retrying in the
    background with no word: a second robot ran alone, its `--without policy` episode waiting for a server it could
    never reach. The router to join must be reachable within the timeout, as a client's is (README: exit 3)."""
    nobody = loopback_endpoint(transport.free_tcp_port())
    with pytest.raises(transport.TransportError, match="Unable to connect") as err:
        transport.open_router(["tcp/127.0.0.1:0"], [nobody], connect_timeout_s=0.5)
    assert err.value.cause == transport.UNREACHABLE
    first, (endpoint,) = transport.open_router(["tcp/127.0.0.1:0"], [])
    with first:
        second, _ = transport.open_router(["tcp/127.0.0.1:0"], [endpoint], connect_timeout_s=5.0)  # there: it joins
        with second:
            assert first.zid() in second.info.routers_zid()


def test_a_tls_router_picks_a_free_port_and_lets_in_only_sessions_that_trust_its_ca(tls_config):
    """``open_router`` with ``tls/127.0.0.1:0``: a free port, as for tcp; a client with the CA joins; one without it,
    or over plain TCP, cannot; a TLS port taken by another process gets ``up``'s hint in TLS, not tcp."""
    from cso_runtime.launcher import transport_error_hint

    session, (endpoint,) = transport.open_router(["tls/127.0.0.1:0"], [], zenoh_config_file=str(tls_config))
    with session:
        assert re.fullmatch(r"tls/127\.0\.0\.1:\d+", endpoint) and not endpoint.endswith(":0"), endpoint
        with transport.open_session(TransportConfig(connect=[endpoint], connect_timeout_s=5.0, zenoh_config_file=str(tls_config))):
            pass
        with pytest.raises(transport.TransportError) as err:  # no CA: the router's certificate is not trusted; no TLS at all
            transport.open_session(TransportConfig(connect=[endpoint, endpoint.replace("tls/", "tcp/", 1)], connect_timeout_s=0.5, zenoh_config_file=""))
        assert err.value.cause == transport.UNREACHABLE, err.value
        with pytest.raises(transport.TransportError) as err:
            transport.open_router([endpoint], [], zenoh_config_file=str(tls_config))
    assert err.value.cause == transport.LISTEN_IN_USE, err.value
    assert "`--set 'router.listen=[tls/127.0.0.1:0]'`" in transport_error_hint(err.value, [endpoint])


def test_a_peer_service_listens_on_loopback_like_its_router():
    """Peer-mode services of a run behind a TLS router listened on plain TCP, where a session without the CA joined
    them (tests/test_runtime.py, the TLS run): a service listens over its router's protocol, tcp for any other."""
    assert transport.any_loopback_port(["tls/127.0.0.1:40001"]) == "tls/127.0.0.1:0"
    assert transport.any_loopback_port(["tcp/127.0.0.1:40001", "tls/127.0.0.1:40002"]) == "tcp/127.0.0.1:0"
    assert transport.any_loopback_port([]) == transport.any_loopback_port(["udp/127.0.0.1:40001"]) == "tcp/127.0.0.1:0"


def test_ups_hint_for_a_router_that_did_not_open_fits_its_cause():
    """``up``'s error when its router did not open asked "is the router to join running?" even when the embedded
    router's own listen port was taken (no router to join at all): the hint names the port and how to pick another;
    "the router to join" only when one to connect to did not answer."""
    from cso_runtime.launcher import transport_error_hint

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        listen = [loopback_endpoint(taken.getsockname()[1])]
        with pytest.raises(transport.TransportError) as err:
            transport.open_router(listen, [])
    hint = transport_error_hint(err.value, listen)
    assert f"another process holds a port the embedded router is to listen on ({listen[0]})" in hint, hint
    assert "router.listen" in hint and "router to join" not in hint, hint
    with pytest.raises(transport.TransportError) as err:
        transport.open_router(["tcp/127.0.0.1:0"], [loopback_endpoint(transport.free_tcp_port())], connect_timeout_s=0.5)
    assert transport_error_hint(err.value, ["tcp/127.0.0.1:0"]) == "is the router to join running and reachable?"


def write_zenoh_config(folder: Path, text: str, name: str = "zenoh.json5") -> Path:
    path = folder / name
    path.write_text(text)
    return path


def test_a_zenoh_config_files_settings_reach_the_session_config_with_ours_on_top(tmp_path, monkeypatch):
    """A user's Zenoh config (credentials, its own queue size) is the base; mode, endpoints and scouting are ours."""
    users = write_zenoh_config(tmp_path, "cso:s3cret\n", "users.txt")
    path = write_zenoh_config(tmp_path, f"""{{
      // Zenoh's own JSON5
      transport: {{ auth: {{ usrpwd: {{ user: "cso", password: "s3cret", dictionary_file: "{users}" }} }},
                   link: {{ tx: {{ queue: {{ size: {{ data: 4 }} }} }} }} }},
      scouting: {{ gossip: {{ enabled: false }} }},
    }}""")
    endpoint = loopback_endpoint(7447)
    cfg = zenoh_config(TransportConfig(mode="client", connect=[endpoint], zenoh_config_file=str(path)))
    assert json.loads(cfg.get_json("transport/auth/usrpwd/user")) == "cso"
    assert json.loads(cfg.get_json("transport/auth/usrpwd/dictionary_file")) == str(users)
    assert cfg.get_json("scouting/gossip/enabled") == "false"
    assert cfg.get_json("transport/link/tx/queue/size/data") == "4"  # the file's own tuning is kept
    assert cfg.get_json("transport/link/tx/queue/congestion_control/drop/wait_before_drop") == "20000"  # ours where it says nothing
    assert json.loads(cfg.get_json("mode")) == "client" and json.loads(cfg.get_json("connect/endpoints")) == [endpoint]
    assert cfg.get_json("scouting/multicast/enabled") == "false" and cfg.get_json("connect/exit_on_failure") == "true"
    monkeypatch.setenv(transport.ZENOH_CONFIG_ENV, str(path))  # what `cso-runtime --zenoh-config` and `up` pass on
    assert TransportConfig(mode="client", connect=[endpoint]).zenoh_config_file == str(path)
    assert json.loads(status.zenoh_config(TransportConfig(mode="client", connect=[endpoint])).get_json("transport/auth/usrpwd/user")) == "cso"


@pytest.mark.parametrize(("text", "said"), [
    (None, "No such file"),
    ("{ transport: ", "expected"),
    ("{ tranport: {} }", "unknown field `tranport`"),
    ('{ mode: "peer" }', "mode is set by cso-runtime"),
    ('{ connect: { endpoints: ["tcp/10.0.0.1:7447"] } }', "connect/endpoints is set by cso-runtime"),
    ("{ scouting: { multicast: { enabled: true } } }", "scouting/multicast/enabled is set by cso-runtime"),
    ('{ transport: { auth: { usrpwd: { dictionary_file: "no-such-users.txt" } } } }', "dictionary_file names 'no-such-users.txt', which is not a file"),
], ids=["missing", "not-json5", "unknown-key", "mode", "endpoints", "multicast", "missing-dictionary"])
def test_a_zenoh_config_file_zenoh_or_the_runtime_would_refuse_is_a_configuration_error(tmp_path, monkeypatch, text, said):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "zenoh.json5" if text is None else write_zenoh_config(tmp_path, text)
    with pytest.raises(transport.TransportError, match=re.escape(said)):
        TransportConfig(mode="client", connect=[loopback_endpoint(7447)], zenoh_config_file=str(path)).validate()
