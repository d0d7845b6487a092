"""`fxswarm keys`, the key-file checks and the rules, without a Zenoh session.

Bad key files are refused before any process starts: one line naming the file, exit 2.
"""

from __future__ import annotations

import datetime as dt
import json
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.x509.oid import ExtendedKeyUsageOID

from fxswarm.cli import main as fxswarm_main
from fxswarm.core.scenario import load
from fxswarm.launch.compose import compose_file
from fxswarm.runtime.tls import KeyFileError, check, checked, common_name, files_for
from fxswarm.security.keys import write_keys
from fxswarm.security.policy import access_control, process_names, rights

REPO = Path(__file__).resolve().parents[2]
SCENARIO = REPO / "configs" / "paper-fast.toml"


@pytest.fixture(scope="module")
def sc():
    return load(SCENARIO)


@pytest.fixture(scope="module")
def keys(tmp_path_factory, sc) -> Path:
    folder = tmp_path_factory.mktemp("keys")
    write_keys(folder, sc)
    return folder


def fxswarm(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fxswarm.cli", *args], capture_output=True, text=True, timeout=120,
                          cwd=cwd)


def test_keys_command_writes_a_ca_and_one_private_pair_per_process(tmp_path, sc):
    out = tmp_path / "k"
    r = fxswarm("keys", str(out), str(SCENARIO), "--days", "30")
    assert r.returncode == 0, r.stderr
    names = ["router", "world", "leader", "logger", "observer", *(f"agent-{i}" for i in range(1, 7))]
    assert process_names(sc) == names
    ca = x509.load_pem_x509_certificate((out / "ca.pem").read_bytes())
    for name in names:
        assert stat.S_IMODE((out / f"{name}.key").stat().st_mode) == 0o600
        cert = x509.load_pem_x509_certificate((out / f"{name}.pem").read_bytes())
        assert common_name(cert) == name and cert.issuer == ca.subject
        assert 29 <= (cert.not_valid_after_utc - cert.not_valid_before_utc).days <= 31
        usage = cert.extensions.get_extension_for_class(x509.ExtendedKeyUsage).value
        # Every process serves TLS (a mesh peer listens) and is a TLS client: rights go by the rules.
        assert {ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH} <= set(usage)
        check(files_for(out, name))
    assert stat.S_IMODE((out / "ca.key").stat().st_mode) == 0o600
    again = fxswarm("keys", str(out), str(SCENARIO))  # never overwritten by accident
    assert again.returncode == 2 and "already holds keys" in again.stderr


def test_adding_a_robot_keeps_the_ca_and_the_other_keys(tmp_path, sc):
    out = tmp_path / "k"
    write_keys(out, sc)
    before = (out / "agent-1.pem").read_bytes()
    (out / "agent-6.pem").unlink()
    (out / "agent-6.key").unlink()
    assert write_keys(out, sc, add=True) == ["agent-6"]
    assert (out / "agent-1.pem").read_bytes() == before
    check(files_for(out, "agent-6"))


def test_force_and_add_together_are_refused_before_any_key_is_written(tmp_path, capsys):
    """--force makes a new CA, --add keeps the old one: given both, --add used to win silently."""
    with pytest.raises(SystemExit) as exc:
        fxswarm_main(["keys", str(tmp_path / "k"), str(SCENARIO), "--force", "--add"])
    assert exc.value.code == 2 and "not allowed with argument --force" in capsys.readouterr().err
    assert not (tmp_path / "k").exists()


def _bad(tmp_path: Path, keys: Path, how: str) -> tuple[Path, Path]:
    """A copy of ``keys`` with agent-3's files spoiled ``how``; the file to be named."""
    folder = tmp_path / how
    shutil.copytree(keys, folder)
    if how == "missing":
        (folder / "agent-3.key").unlink()
        return folder, folder / "agent-3.key"
    if how == "missing-cert":
        (folder / "agent-3.pem").unlink()
        return folder, folder / "agent-3.pem"
    if how == "unreadable":  # a folder in place of the file: unreadable even by root
        (folder / "agent-3.pem").unlink()
        (folder / "agent-3.pem").mkdir()
        return folder, folder / "agent-3.pem"
    if how == "expired":
        old = tmp_path / "old"
        write_keys(old, load(SCENARIO), days=1, now=dt.datetime.now(dt.timezone.utc) - dt.timedelta(days=3))
        for f in ("ca.pem", "agent-3.pem", "agent-3.key"):
            shutil.copy(old / f, folder / f)
        return folder, folder / "ca.pem"
    if how == "wrong-ca":
        other = tmp_path / "other"
        write_keys(other, load(SCENARIO))
        for f in ("agent-3.pem", "agent-3.key"):
            shutil.copy(other / f, folder / f)
        return folder, folder / "agent-3.pem"
    if how == "wrong-key":
        shutil.copy(folder / "agent-4.key", folder / "agent-3.key")
        return folder, folder / "agent-3.key"
    raise ValueError(how)


@pytest.mark.parametrize("how,says", [("missing", "missing"), ("missing-cert", "missing"), ("unreadable", "cannot read"),
                                      ("expired", "expired"), ("wrong-ca", "does not verify"),
                                      ("wrong-key", "does not belong")])
def test_a_bad_key_file_is_named_and_nothing_starts(tmp_path, keys, how, says, fxswarm_here):
    folder, named = _bad(tmp_path, keys, how)
    with pytest.raises(KeyFileError, match=says) as err:
        checked(folder, "agent-3")
    assert str(named) in str(err.value)
    assert "not a PEM" not in str(err.value) and "not an unencrypted" not in str(err.value), err.value  # not its format
    out = tmp_path / "run"
    code, _, err = fxswarm_here("run", SCENARIO, "--secure", folder, "--out", out, "--quiet")
    assert code == 2, err
    assert str(named) in err and says in err
    assert not (out / "logs").exists()  # no process was started
    code, _, err = fxswarm_here("agent", SCENARIO, "--id", "3", "--secure", folder, "--connect", "tls/127.0.0.1:9")
    assert code == 2 and str(named) in err


@pytest.mark.parametrize("how,says", [("missing", "missing"), ("wrong-ca", "does not verify")])
def test_attach_names_a_bad_key_file_before_it_connects(tmp_path, keys, how, says, fxswarm_here):
    folder = tmp_path / "keys"
    shutil.copytree(keys, folder)
    named = folder / "observer.pem"
    if how == "missing":
        named.unlink()
    else:
        other = tmp_path / "other"
        write_keys(other, load(SCENARIO))
        shutil.copy(other / "observer.pem", named)
        shutil.copy(other / "observer.key", folder / "observer.key")
    out = tmp_path / "seen"
    # Port 9 (discard): nothing answers there, so only a check before connecting ends this at once.
    code, _, err = fxswarm_here("attach", "tls/127.0.0.1:9", "--swarm", "s", "--out", out, "--secure", folder,
                                "--timeout", "30")
    assert code == 2, err
    (line,) = err.strip().splitlines()
    assert str(named) in line and says in line
    assert not out.exists()
    code, _, err = fxswarm_here("attach", "tcp/127.0.0.1:9", "--swarm", "s", "--out", out, "--secure", keys)
    assert code == 2 and "tls/HOST:PORT" in err and not out.exists()


def test_secure_mode_is_plaintext_free_and_an_audited_run_is_routed(tmp_path, keys, fxswarm_here):
    code, _, err = fxswarm_here("run", SCENARIO, "--secure", keys, "--audit", "--topology", "mesh",
                                "--out", tmp_path / "r")
    assert code == 2 and "routed" in err
    code, _, err = fxswarm_here("agent", SCENARIO, "--id", "1", "--secure", keys, "--connect", "tcp/127.0.0.1:7447")
    assert code == 2 and "tls/" in err
    code, _, err = fxswarm_here("world", SCENARIO, "--secure", keys, "--mode", "peer", "--connect", "tls/127.0.0.1:9",
                                "--listen", "tcp/127.0.0.1:0")
    assert code == 2 and "--listen tcp/127.0.0.1:0" in err and "tls/" in err
    code, _, err = fxswarm_here("world", SCENARIO, "--secure", keys, "--mode", "router", "--connect", "tls/127.0.0.1:9")
    assert code == 2 and "client" in err
    code, _, err = fxswarm_here("world", SCENARIO, "--mode", "peer", "--access", keys / "access.json")
    assert code == 2 and "--secure" in err
    code, _, err = fxswarm_here("router", "--secure", keys, "--listen", "tcp/127.0.0.1:0")
    assert code == 2 and "tls/" in err


def test_rights_follow_the_nodes_subscriptions_and_the_graph(sc):
    r = rights(sc)
    # Robot 1: neighbours 2 and 6, pinned; robot 2: neighbours 1 and 3, not pinned.
    # A neighbour's estimate rides on its command: a robot hears its neighbours' command keys;
    # and the world asking again after a router outage (world/again).
    assert sorted(r["agent-1"]["hear"]) == sorted(["world/sense/1", "agent/2/cmd", "agent/6/cmd", "leader/state",
                                                   "world/again"])
    assert sorted(r["agent-2"]["hear"]) == sorted(["world/sense/2", "agent/1/cmd", "agent/3/cmd", "world/again"])
    assert r["leader"]["hear"] == ["world/sense/1", "world/again"] and r["world"]["put"] == ["world/**"]
    assert r["agent-2"]["put"] == ["agent/2/**"] and r["logger"]["put"] == [] and r["observer"]["put"] == []
    # The world: every robot's commands, and the leader's states (a real-time world waits for a lagging leader).
    assert sorted(r["world"]["hear"]) == sorted([*(f"agent/{i}/cmd" for i in range(1, 7)), "leader/state"])
    acl = access_control(sc, "s")
    assert acl["default_permission"] == "deny" and acl["enabled"]
    by_id = {rule["id"]: rule for rule in acl["rules"]}
    assert by_id["agent-2-put"]["key_exprs"] == ["fxswarm/s/agent/2/**"]
    assert by_id["agent-2-put"]["flows"] == ["ingress"]
    subjects = {s["id"]: s["cert_common_names"] for s in acl["subjects"]}
    assert sorted(n for names in subjects.values() for n in names) == sorted(process_names(sc))


def test_the_observer_may_ask_for_the_scenario_and_the_record_and_announce_itself_and_no_more(sc):
    """`fxswarm attach --secure` shows the observer's certificate: it reads world/state, asks the router
    for the scenario and the world for its record (a query in, its reply out) and declares an observer
    token; it says nothing else. Only the world may answer world/record (issue 29)."""
    r = rights(sc)
    asked = ["fxswarm/s/scenario", "fxswarm/s/world/record"]
    assert r["observer"] == {"put": [], "hear": ["world/state"], "tokens": ["alive/observer/*"],
                             "ask": ["scenario", "world/record"]}
    assert all(not rights_.get("ask") for name, rights_ in r.items() if name != "observer")
    assert {name: rights_["answer"] for name, rights_ in r.items() if rights_.get("answer")} == {"world": ["world/record"]}
    acl = access_control(sc, "s")
    by_id = {rule["id"]: rule for rule in acl["rules"]}
    assert by_id["observer-ask"] == {"id": "observer-ask", "messages": ["query"], "flows": ["ingress"],
                                     "permission": "allow", "key_exprs": asked}
    assert by_id["observer-answer"] == {"id": "observer-answer", "messages": ["reply"], "flows": ["egress"],
                                        "permission": "allow", "key_exprs": asked}
    assert by_id["world-serve"] == {"id": "world-serve", "messages": ["declare_queryable", "reply"],
                                    "flows": ["ingress"], "permission": "allow", "key_exprs": ["fxswarm/s/world/record"]}
    assert by_id["world-asked"] == {"id": "world-asked", "messages": ["query"], "flows": ["egress"],
                                    "permission": "allow", "key_exprs": ["fxswarm/s/world/record"]}
    assert by_id["observer-token"]["key_exprs"] == ["fxswarm/s/alive/observer/*"]
    # No other rule lets anyone query, serve, nor be sent a reply outside liveliness; but routers
    # meshed with each other, which forward all (the `router` certificate alone).
    queries = [rule["id"] for rule in acl["rules"] if "query" in rule["messages"]]
    replies = [rule["id"] for rule in acl["rules"] if "reply" in rule["messages"]]
    serves = [rule["id"] for rule in acl["rules"] if "declare_queryable" in rule["messages"]]
    assert sorted(queries) == ["observer-ask", "routers-forward", "world-asked"]
    assert sorted(serves) == ["routers-forward", "world-serve"]
    assert sorted(replies) == ["liveliness-news", "observer-answer", "routers-forward", "world-serve"]
    (routers,) = [p for p in acl["policies"] if "routers-forward" in p["rules"]]
    assert routers["subjects"] == ["s-router"] and {"id": "s-router", "cert_common_names": ["router"]} in acl["subjects"]
    (mine,) = [p for p in acl["policies"] if p["id"] == "p-observer"]
    assert sorted(mine["rules"]) == ["observer-answer", "observer-ask", "observer-hear", "observer-subscribe",
                                     "observer-token"]


def test_secure_compose_gives_each_service_its_own_key_as_secrets(tmp_path, sc, keys):
    text = compose_file(sc, "configs/paper-fast.toml", tmp_path, REPO, keys=keys)
    assert "tcp/" not in text and '"tls/router:7447"' in text
    # Each agent service holds the CA and its own pair only, as secrets from files in KEYS.
    block = text.split("\n  agent-3:\n")[1].split("\n\n")[0]
    assert 'secrets: ["ca.pem", "agent-3.pem", "agent-3.key"]' in block
    assert '"${FXSWARM_UID:-10001}:${FXSWARM_GID:-10001}"' in block
    tail = text.split("\nsecrets:\n")[1]
    assert f'file: "{keys}/agent-3.key"' in tail or 'agent-3.key:\n    file:' in tail
    assert "FXSWARM_SECURE" in text and json.loads((keys / "access.json").read_text())["default_permission"] == "deny"


def test_a_mesh_peer_needs_a_server_certificate_and_the_rules(tmp_path, keys, fxswarm_here):
    """Keys of an older fxswarm (only the router's certificate could serve TLS) are named up front, as is
    a missing rules file; a client still takes them."""
    from fxswarm.security.keys import _cert_pem, _key_pem, make_ca, make_leaf

    old = tmp_path / "old"
    old.mkdir()
    ca_key, ca = make_ca(30)
    (old / "ca.pem").write_bytes(_cert_pem(ca))
    key, cert = make_leaf("agent-1", ca_key, ca, 30)
    cert_without_server = (x509.CertificateBuilder().subject_name(cert.subject).issuer_name(cert.issuer)
                           .public_key(cert.public_key()).serial_number(cert.serial_number)
                           .not_valid_before(cert.not_valid_before_utc).not_valid_after(cert.not_valid_after_utc)
                           .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
                           .sign(ca_key, cert.signature_hash_algorithm))
    (old / "agent-1.pem").write_bytes(_cert_pem(cert_without_server))
    (old / "agent-1.key").write_bytes(_key_pem(key))
    checked(old, "agent-1")  # a client: fine
    with pytest.raises(KeyFileError, match="not a TLS server certificate") as err:
        checked(old, "agent-1", server=True)
    assert str(old / "agent-1.pem") in str(err.value)
    code, _, err = fxswarm_here("agent", SCENARIO, "--id", "1", "--secure", old, "--mode", "peer",
                                "--connect", "tls/127.0.0.1:9")
    assert code == 2 and "agent-1.pem" in err and "server" in err
    code, _, err = fxswarm_here("agent", SCENARIO, "--id", "1", "--secure", keys, "--mode", "peer",
                                "--connect", "tls/127.0.0.1:9", "--access", tmp_path / "nowhere.json")
    assert code == 2 and "nowhere.json: missing" in err


def test_each_secure_session_trusts_only_the_router_to_forward_and_a_peer_enforces_the_rules(sc):
    from fxswarm.runtime.tls import session_rules

    client = session_rules("client", None)
    assert client["default_permission"] == "deny"
    assert [s["cert_common_names"] for s in client["subjects"]] == [["router"]]
    acl = access_control(sc, "s")
    peer = session_rules("peer", acl)
    assert peer["rules"][:len(acl["rules"])] == acl["rules"] and len(peer["subjects"]) == len(acl["subjects"]) + 1
    with pytest.raises(ValueError, match="--access"):
        session_rules("peer", None)
