"""Secure deployment: `followbot certs`, the Zenoh security settings, the access rules, and
compose/split_secure.yaml across two hosts (network namespaces) with an intruder."""

from __future__ import annotations

import json
import os
import random
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import msgspec
import pytest
from conftest import REPO
from netns import two_hosts, unavailable

from followbot.certs import CertError, make_certs
from followbot.certs import main as certs_main
from followbot.services.runtime.bus import FakeBus, FakeNetwork
from followbot.services.runtime.compose import ComposeError, load_compose, service_settings
from followbot.services.runtime.node import Node
from followbot.services.runtime.security import ROLES, AccessSettings, access_control
from followbot.services.runtime.session import (
    add_zenoh_arguments,
    overrides_from_args,
    zenoh_config,
)
from followbot.services.runtime.settings import NodeSettings, ZenohSettings, load_settings

SECURE = REPO / "compose" / "split_secure.yaml"


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> Path:
    """One CA with the identities of split_secure.yaml, and `intruder` (signed, no rights)."""
    folder = tmp_path_factory.mktemp("certs")
    make_certs(folder, ["router", "sim", "laser_legs", "tracker", "controller",
                        "vision_verify", "operator"])  # fmt: skip
    return folder


def _cert(path: Path):
    from cryptography import x509

    return x509.load_pem_x509_certificate(path.read_bytes())


def _cn(cert) -> str:
    from cryptography.x509.oid import NameOID

    return cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value


# ----------------------------------------------------------------------------- followbot certs


def test_certs_makes_a_ca_and_one_certificate_per_identity_named_by_its_common_name(tmp_path):
    argv = [str(tmp_path / "c"), "--identity", "tracker", "--identity", "operator",
            "--router-host", "10.1.2.3", "--router-host", "robot.local"]  # fmt: skip
    assert certs_main(argv) == 0
    c = tmp_path / "c"
    ca = _cert(c / "ca.pem")
    for name in ("router", "tracker", "operator"):  # the router is added: a CA needs one
        cert = _cert(c / f"{name}.pem")
        assert _cn(cert) == name
        cert.verify_directly_issued_by(ca)  # raises if the CA did not sign it
        assert (c / f"{name}.password").read_text().strip()
    from cryptography import x509

    sans = _cert(c / "router.pem").extensions.get_extension_for_class(x509.SubjectAlternativeName)
    names = {str(v) for v in sans.value.get_values_for_type(x509.IPAddress)}
    assert names == {"127.0.0.1", "10.1.2.3"}
    assert set(sans.value.get_values_for_type(x509.DNSName)) == {"localhost", "robot.local"}
    users = dict(line.split(":", 1) for line in (c / "users.txt").read_text().splitlines())
    assert users == {n: (c / f"{n}.password").read_text().strip()
                     for n in ("router", "tracker", "operator")}  # fmt: skip


def test_certs_keys_passwords_and_the_users_file_are_readable_by_the_owner_only(tmp_path):
    make_certs(tmp_path, ["router", "operator"])
    for f in ("ca.key", "router.key", "operator.key", "operator.password", "users.txt"):
        assert stat.S_IMODE((tmp_path / f).stat().st_mode) == 0o600, f
    for f in ("ca.pem", "operator.pem"):
        assert stat.S_IMODE((tmp_path / f).stat().st_mode) == 0o644, f


def test_certs_refuses_to_overwrite_unless_forced(tmp_path, capsys):
    assert certs_main([str(tmp_path), "--identity", "router"]) == 0
    before = (tmp_path / "ca.pem").read_bytes(), (tmp_path / "router.key").read_bytes()
    capsys.readouterr()
    assert certs_main([str(tmp_path), "--identity", "router"]) == 1
    err = capsys.readouterr().err
    assert "already exist" in err and "--force" in err
    assert ((tmp_path / "ca.pem").read_bytes(), (tmp_path / "router.key").read_bytes()) == before
    assert certs_main([str(tmp_path), "--identity", "router", "--force"]) == 0
    assert (tmp_path / "ca.pem").read_bytes() != before[0]  # a new CA
    assert (tmp_path / "router.key").read_bytes() != before[1]


def test_certs_adds_an_identity_signed_by_the_existing_ca(tmp_path):
    make_certs(tmp_path, ["router", "operator"])
    ca = (tmp_path / "ca.pem").read_bytes()
    assert certs_main([str(tmp_path), "--identity", "console2"]) == 0
    assert (tmp_path / "ca.pem").read_bytes() == ca
    _cert(tmp_path / "console2.pem").verify_directly_issued_by(_cert(tmp_path / "ca.pem"))
    users = [line.split(":")[0] for line in (tmp_path / "users.txt").read_text().splitlines()]
    assert users == ["router", "operator", "console2"]


def test_certs_takes_the_identities_of_a_compose_file(tmp_path):
    assert certs_main([str(tmp_path), "--compose", str(SECURE)]) == 0
    made = sorted(p.stem for p in tmp_path.glob("*.pem") if p.stem != "ca")
    assert made == sorted(["router", "sim", "laser_legs", "tracker", "controller",
                           "vision_verify", "operator"])  # fmt: skip


def test_certs_rejects_a_bad_identity_name_and_a_bad_router_host(tmp_path):
    with pytest.raises(CertError, match="identity 'a/b'"):
        make_certs(tmp_path, ["a/b"])
    with pytest.raises(CertError, match="--router-host"):
        make_certs(tmp_path, ["router"], router_hosts=["tcp/1.2.3.4:7447"])
    assert not any(tmp_path.iterdir())


def test_certs_help_explains_the_files(capsys):
    with pytest.raises(SystemExit):
        certs_main(["--help"])
    out = capsys.readouterr().out
    assert "ca.key" in out and "users.txt" in out and "--force" in out and "0600" in out


# ----------------------------------------------------------------------------- settings -> zenoh


def _get(conf, key):
    return json.loads(conf.get_json(key))


def _zenoh(**fields) -> ZenohSettings:
    return msgspec.convert(fields, ZenohSettings)


def test_tls_and_auth_settings_become_zenoh_mutual_tls_and_user_password(certs):
    z = _zenoh(
        mode="client",
        connect=["tls/127.0.0.1:7447"],
        tls={"ca": str(certs / "ca.pem"), "cert": str(certs / "tracker.pem"),
             "key": str(certs / "tracker.key")},
        auth={"user": "tracker", "password_file": str(certs / "tracker.password")},
    )  # fmt: skip
    conf = zenoh_config(z)
    tls = _get(conf, "transport/link/tls")
    assert tls["enable_mtls"] is True and tls["verify_name_on_connect"] is True
    assert tls["root_ca_certificate"] == str(certs / "ca.pem")
    assert tls["connect_certificate"] == str(certs / "tracker.pem")
    assert tls["connect_private_key"] == str(certs / "tracker.key")
    assert _get(conf, "transport/auth/usrpwd/user") == "tracker"
    # the password is read from its file (settings and up's settings files hold only the path)
    password = (certs / "tracker.password").read_text().strip()
    assert password and _get(conf, "transport/auth/usrpwd/password") == password


def test_zenoh_config_file_still_applies_under_the_security_settings(tmp_path, certs):
    f = tmp_path / "z.json5"
    f.write_text("{ transport: { link: { tx: { batch_size: 4096 } } } }")
    z = _zenoh(mode="client", connect=["tls/127.0.0.1:7447"], config=str(f),
                      tls={"ca": str(certs / "ca.pem"), "cert": str(certs / "operator.pem"),
                           "key": str(certs / "operator.key")})  # fmt: skip
    conf = zenoh_config(z)
    assert _get(conf, "transport/link/tx/batch_size") == 4096
    assert _get(conf, "transport/link/tls/enable_mtls") is True


_TLS = {"ca": "X/ca.pem", "cert": "X/tracker.pem", "key": "X/tracker.key"}


@pytest.mark.parametrize(
    "change, error",
    [
        ({"tls": {"ca": "X/ca.pem"}}, "ca, cert and key go together; missing cert"),
        ({"connect": ["tcp/127.0.0.1:7447"]}, "must be tls/host:port"),
        ({"connect": []}, "must be tls/host:port"),
        ({"tls": {**_TLS, "cert": "X/nope.pem"}}, "zenoh.tls.cert: no file"),
        ({"auth": {"user": "tracker"}}, "user and password_file go together"),
        ({"access": {"identities": {"tracker": ["tracker"]}}}, "zenoh.access.robot"),
        ({"access": {"robot": "r", "identities": {"x": ["pilot"]}}}, "unknown role 'pilot'"),
        ({"tls": {}, "access": {"robot": "r", "identities": {"x": ["operator"]}}},
         "zenoh.access needs zenoh.tls"),
    ],
)  # fmt: skip
def test_inconsistent_security_settings_fail_with_the_setting_named(certs, change, error):
    data = {"mode": "peer", "connect": ["tls/127.0.0.1:7447"], "tls": _TLS} | change
    text = json.dumps(data).replace("X/", f"{certs}/")
    with pytest.raises(ValueError, match=error):
        zenoh_config(msgspec.convert(json.loads(text), ZenohSettings))


def test_a_tls_peer_without_listen_endpoints_listens_nowhere(certs):
    z = _zenoh(connect=["tls/127.0.0.1:7447"],
                      tls={"ca": str(certs / "ca.pem"), "cert": str(certs / "sim.pem"),
                           "key": str(certs / "sim.key")})  # fmt: skip
    assert _get(zenoh_config(z), "listen/endpoints") == []


def test_the_identity_option_names_the_files_of_followbot_certs(certs):
    import argparse

    p = argparse.ArgumentParser()
    add_zenoh_arguments(p)
    args = p.parse_args(["--identity", f"{certs}/operator", "--connect", "tls/10.0.0.1:7447"])
    s = load_settings(NodeSettings, None, overrides_from_args(args))
    assert s.zenoh.tls.cert == f"{certs}/operator.pem" and s.zenoh.tls.ca == f"{certs}/ca.pem"
    assert s.zenoh.tls.key == f"{certs}/operator.key"
    assert s.zenoh.auth.user == "operator"
    assert s.zenoh.auth.password_file == f"{certs}/operator.password"


# ----------------------------------------------------------------------------- access rules


def _allowed(acl: dict, identity: str, message: str, key: str) -> bool:
    """Whether the generated rules let ``identity`` send ``message`` on ``key`` (ingress):
    a reading of the rules as zenoh applies them, for literal keys and ``/**`` patterns."""
    rules = {r["id"]: r for r in acl["rules"]}
    for policy in acl["policies"]:
        if identity not in policy["subjects"]:
            continue
        for rid in policy["rules"]:
            r = rules[rid]
            if "ingress" in r["flows"] and message in r["messages"]:
                for k in r["key_exprs"]:
                    if k == key or (k.endswith("/**") and key.startswith(k[:-2])):
                        return True
    return False


def test_each_topic_has_one_legitimate_publisher_in_the_rules():
    identities = {n: [n] for n in ("sim", "laser_legs", "tracker", "controller",
                                   "vision_verify", "router")}  # fmt: skip
    identities["operator"] = ["operator"]
    acl = access_control(AccessSettings(robot="r1", identities=identities))
    assert acl["default_permission"] == "deny"
    expected = {
        "control/cmd_vel": {"controller"},
        "control/pan": {"controller"},
        "tracking/target": {"tracker"},
        "tracking/people": {"tracker"},
        "perception/target_command": {"operator"},
        "perception/candidates": {"laser_legs"},
        "perception/verification": {"vision_verify"},
        "perception/target_model": {"vision_verify"},
        "sensors/scan": {"sim"},
        "sim/truth": {"sim"},
    }
    for topic, publishers in expected.items():
        allowed = {i for i in identities if _allowed(acl, i, "put", f"followbot/r1/{topic}")}
        assert allowed == publishers, topic
    # presence and health: each only its own
    assert _allowed(acl, "tracker", "liveliness_token", "followbot/r1/alive/tracker")
    assert not _allowed(acl, "vision_verify", "liveliness_token", "followbot/r1/alive/tracker")
    assert not _allowed(acl, "operator", "put", "followbot/r1/health/controller")
    # the recovered target model: answered by the tracker and vision, asked by vision
    key = "followbot/r1/perception/target_model"
    assert {i for i in identities if _allowed(acl, i, "reply", key)} == {"tracker", "vision_verify"}
    assert {i for i in identities if _allowed(acl, i, "query", key)} == {"vision_verify"}
    # another robot's keys: nobody
    assert not _allowed(acl, "controller", "put", "followbot/r2/control/cmd_vel")
    # everyone may subscribe
    assert all(_allowed(acl, i, "declare_subscriber", "followbot/r1/sensors/scan")
               for i in identities)  # fmt: skip


def test_a_process_of_several_services_plays_each_of_their_roles():
    acl = access_control(
        AccessSettings(robot="r1", identities={"core": ["laser_legs", "tracker", "controller"]})
    )
    for topic in ("perception/candidates", "tracking/target", "control/cmd_vel",
                  "health/tracker", "health/controller"):  # fmt: skip
        assert _allowed(acl, "core", "put", f"followbot/r1/{topic}"), topic
    assert not _allowed(acl, "core", "put", "followbot/r1/perception/target_command")


def test_the_router_passes_presence_health_and_queries_only_as_the_roles_say(certs, endpoint):
    """Real Zenoh sessions (TLS, passwords, the generated rules at a router): a service's own
    liveliness token comes and goes, a token or Health under another service's name is
    dropped, and only roles that may ask get the target model."""
    from followbot.services.runtime.session import open_session

    tls_endpoint = endpoint.replace("tcp/", "tls/")

    def settings(identity: str, **kw) -> ZenohSettings:
        tls = {"ca": str(certs / "ca.pem"), "cert": str(certs / f"{identity}.pem"),
               "key": str(certs / f"{identity}.key")}  # fmt: skip
        return _zenoh(tls=tls, **kw)

    def client(identity: str):
        auth = {"user": identity, "password_file": str(certs / f"{identity}.password")}
        return open_session(settings(identity, mode="client", connect=[tls_endpoint], auth=auth))

    access = {"robot": "r1", "identities": {n: [n] for n in ("tracker", "vision_verify",
                                                               "operator")}}  # fmt: skip
    router = open_session(settings("router", mode="router", listen=[tls_endpoint],
                                   auth={"dictionary_file": str(certs / "users.txt")},
                                   access=access))  # fmt: skip
    sessions = [router]
    try:
        tracker = client("tracker")
        sessions.append(tracker)
        alive, health = [], []
        tracker.liveliness().declare_subscriber(
            "followbot/r1/alive/*",
            lambda s: alive.append((str(s.key_expr).rsplit("/", 1)[1], str(s.kind))),
            history=True,
        )
        tracker.declare_subscriber(
            "followbot/r1/health/*", lambda s: health.append(str(s.key_expr).rsplit("/", 1)[1])
        )
        tracker.declare_queryable(
            "followbot/r1/perception/target_model",
            lambda q: q.reply("followbot/r1/perception/target_model", b"model 1"),
        )
        vision = client("vision_verify")
        vision.liveliness().declare_token("followbot/r1/alive/vision_verify")
        vision.liveliness().declare_token("followbot/r1/alive/controller")  # not its own
        time.sleep(0.5)
        vision.put("followbot/r1/health/vision_verify", b"ok")
        vision.put("followbot/r1/health/controller", b"ok")  # not its own
        time.sleep(0.5)
        vision.close()  # the vision process goes away: its token with it
        deadline = time.monotonic() + 5
        while len(alive) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert alive == [
            ("vision_verify", "SampleKind.PUT"),
            ("vision_verify", "SampleKind.DELETE"),
        ]
        assert health == ["vision_verify"]
        operator, vision2 = client("operator"), client("vision_verify")
        sessions += [operator, vision2]

        def ask(session) -> list[bytes]:
            replies = session.get("followbot/r1/perception/target_model", timeout=2.0)
            return [r.ok.payload.to_bytes() for r in replies if r.ok is not None]

        assert ask(vision2) == [b"model 1"]
        assert ask(operator) == []
    finally:
        for session in reversed(sessions):
            session.close()


class _RecordingBus(FakeBus):
    """A fake bus that notes what a service declares."""

    def __init__(self, net):
        super().__init__(net)
        self.publishers, self.queryables, self.queries = set(), set(), set()

    def publisher(self, key, *, reliable=False):
        self.publishers.add(key)
        return super().publisher(key, reliable=reliable)

    def queryable(self, key, handler):
        self.queryables.add(key)
        return super().queryable(key, handler)

    def query(self, key, timeout_s):
        self.queries.add(key)
        return super().query(key, timeout_s)


def _service_setups():
    from followbot.services.camera_blobs.node import CameraBlobsSettings
    from followbot.services.camera_blobs.node import setup as camera_blobs
    from followbot.services.controller.node import ControllerNodeSettings
    from followbot.services.controller.node import setup as controller
    from followbot.services.laser_legs.node import LaserLegsSettings
    from followbot.services.laser_legs.node import setup as laser_legs
    from followbot.services.laser_odometry.node import LaserOdometrySettings
    from followbot.services.laser_odometry.node import setup as laser_odometry
    from followbot.services.runtime.monitor import MonitorSettings
    from followbot.services.runtime.monitor import setup as monitor
    from followbot.services.runtime.router import RouterSettings
    from followbot.services.runtime.router import setup as router
    from followbot.services.sim.node import SimSettings
    from followbot.services.sim.node import setup as sim
    from followbot.services.sim.synthetic import SyntheticSettings
    from followbot.services.sim.synthetic import setup as synthetic
    from followbot.services.tracker.node import TrackerNodeSettings
    from followbot.services.tracker.node import setup as tracker
    from followbot.services.vision_verify.node import VisionVerifySettings
    from followbot.services.vision_verify.node import setup as vision_verify

    return {
        "sim": (SimSettings, sim),
        "synthetic": (SyntheticSettings, synthetic),
        "laser_legs": (LaserLegsSettings, laser_legs),
        "camera_blobs": (CameraBlobsSettings, camera_blobs),
        "laser_odometry": (LaserOdometrySettings, laser_odometry),
        "vision_verify": (VisionVerifySettings, vision_verify),
        "tracker": (TrackerNodeSettings, tracker),
        "controller": (ControllerNodeSettings, controller),
        "monitor": (MonitorSettings, monitor),
        "router": (RouterSettings, router),
    }


@pytest.mark.parametrize("service", sorted(_service_setups()))
def test_the_rights_of_a_role_are_what_its_service_declares(service):
    """ROLES must match the code: a service that starts publishing a new topic needs a rule
    (or the router drops it), and a right nobody uses is a right too many."""
    settings_type, setup = _service_setups()[service]
    extra = ["colour={hue_lo: 0, hue_hi: 10, sat_lo: 80, sat_hi: 255}"]  # camera_blobs needs one
    overrides = ["robot=r1", "log_level=error", *(extra if service == "camera_blobs" else [])]
    settings = load_settings(settings_type, None, overrides)
    bus = _RecordingBus(FakeNetwork())
    node = Node(service, settings, bus)
    try:
        setup(node, settings)
    finally:
        node.close()
    role = ROLES[service]
    root = "followbot/r1/"
    declared = {k.removeprefix(root) for k in bus.publishers} - {f"health/{service}"}
    assert declared == set(role.publishes) | set(role.answers)
    assert {k.removeprefix(root) for k in bus.queryables} == set(role.answers)
    assert {k.removeprefix(root) for k in bus.queries} <= set(role.asks)


# ----------------------------------------------------------------------------- compose


def test_split_secure_gives_each_process_its_certificate_and_the_router_the_rules(
    certs, monkeypatch
):
    monkeypatch.setenv("FOLLOWBOT_CERTS", str(certs))
    monkeypatch.setenv("ROBOT_HOST", "10.9.8.1")
    compose = load_compose(SECURE)
    tracker = service_settings(compose, "tracker")["zenoh"]
    assert tracker["mode"] == "client" and tracker["connect"] == ["tls/10.9.8.1:7447"]
    assert tracker["tls"]["cert"] == str(certs / "tracker.pem")
    assert tracker["auth"] == {"user": "tracker",
                               "password_file": str(certs / "tracker.password")}  # fmt: skip
    assert "access" not in tracker
    router = service_settings(compose, "router")["zenoh"]
    assert router["listen"] == ["tls/10.9.8.1:7447"]  # the robot's address, not 0.0.0.0
    assert router["auth"] == {"dictionary_file": str(certs / "users.txt")}
    assert router["access"]["identities"]["operator"] == ["operator"]
    assert router["access"]["identities"]["controller"] == ["controller"]
    # what each process would open a session with (files checked, rules built)
    for name in compose.services:
        settings = load_settings(NodeSettings, None, [], base={"zenoh": service_settings(
            compose, name)["zenoh"]})  # fmt: skip
        zenoh_config(settings.zenoh)


def test_split_secure_names_the_missing_certificate_and_how_to_make_it(tmp_path, monkeypatch):
    make_certs(tmp_path, ["router", "operator"])  # made for another file: no tracker
    monkeypatch.setenv("FOLLOWBOT_CERTS", str(tmp_path))
    compose = load_compose(SECURE)
    service_settings(compose, "router")
    with pytest.raises(ComposeError, match=r"tracker.pem.*followbot certs"):
        service_settings(compose, "tracker")


def test_services_of_one_process_share_one_identity_with_the_rights_of_each(tmp_path):
    from followbot.services.runtime.compose import group_settings

    make_certs(tmp_path / "certs", ["router", "core", "operator"])
    path = tmp_path / "c.yaml"
    path.write_text(
        f"robot: r1\nsecurity: {{certs: {tmp_path / 'certs'}}}\n"
        "zenoh: {mode: client, connect: [tls/127.0.0.1:7447]}\n"
        "services:\n"
        "  router: {settings: {zenoh: {mode: router, connect: [], "
        "listen: [tls/127.0.0.1:7447]}}}\n"
        "  laser_legs: {process: core}\n  tracker: {process: core}\n"
        "  controller: {process: core}\n"
    )
    compose = load_compose(path)
    group = group_settings(compose, ["laser_legs", "tracker", "controller"])
    assert group["zenoh"]["tls"]["cert"] == str(tmp_path / "certs" / "core.pem")
    assert group["zenoh"]["auth"]["user"] == "core"
    access = service_settings(compose, "router")["zenoh"]["access"]
    assert access["identities"] == {"router": ["router"], "core": ["laser_legs", "tracker",
                                    "controller"], "operator": ["operator"]}  # fmt: skip


def test_a_security_section_naming_no_router_entry_is_refused(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("security: {certs: c, router: hub}\nservices: {monitor: {}}\n")
    with pytest.raises(ComposeError, match=r"security\.router: no service 'hub'"):
        load_compose(path)


# ----------------------------------------------------------------------------- two hosts

reason = unavailable()
two_host = [
    pytest.mark.multiprocess,
    pytest.mark.skipif(reason is not None, reason=f"two-host tests skipped: {reason}"),
]


# An intruder on the offboard machine holding vision_verify's certificate and password (a
# member of the deployment, but not the controller or the operator): it reads the robot's
# track, then tries to turn the robot and to save the target model where it likes.
ATTACKER = """
import argparse, time
from followbot.schemas import TargetCommand, VelocityCommand
from followbot.services.runtime.node import zenoh_node
from followbot.services.runtime.session import add_zenoh_arguments, overrides_from_args
from followbot.services.runtime.settings import NodeSettings, load_settings

p = argparse.ArgumentParser()
p.add_argument("path")
add_zenoh_arguments(p)
args = p.parse_args()
settings = load_settings(NodeSettings, None, [*overrides_from_args(args), "log_level=warning"])
seen = []
with zenoh_node("vision_verify_2", settings) as node:
    node.subscribe("tracking/target", seen.append)
    cmd = node.publisher("control/cmd_vel")
    target = node.publisher("perception/target_command", reliable=True)
    for i in range(60):
        cmd.put(VelocityCommand(stamp_ns=time.time_ns(), linear_mps=0.0, angular_radps=1.234,
                                reason="attacker"))
        if i % 20 == 0:
            target.put(TargetCommand(stamp_ns=time.time_ns(), action="save", path=args.path))
        time.sleep(0.05)
print(f"attacker read {len(seen)} track messages", flush=True)
"""


@pytest.mark.multiprocess
@pytest.mark.skipif(reason is not None, reason=f"two-host tests skipped: {reason}")
def test_split_secure_admits_only_its_certificates_and_each_topic_only_from_its_publisher(
    tmp_path, robot
):
    """compose/split_secure.yaml on two hosts (network namespaces): the robot follows with
    vision offboard; a process without a certificate of the deployment's CA cannot connect;
    one with a valid certificate but the wrong identity reads, but neither drives the robot
    nor touches the target model; the operator's identity does."""
    from followbot.bags import open_recording

    with two_hosts() as (bot, off):
        certs, other = tmp_path / "certs", tmp_path / "other"
        make_certs(certs, ["router", "sim", "laser_legs", "tracker", "controller",
                           "vision_verify", "operator"], router_hosts=[bot.address])  # fmt: skip
        make_certs(other, ["router", "operator"])  # another CA: not of this deployment
        port = random.randrange(20000, 60000)
        endpoint = f"tls/{bot.address}:{port}"
        env = dict(os.environ, PYTHONUNBUFFERED="1", RUST_LOG="off", ROBOT_HOST=bot.address,
                   FOLLOWBOT_PORT=str(port), FOLLOWBOT_ROBOT=robot, FOLLOWBOT_CERTS=str(certs),
                   FOLLOWBOT_SCENARIO="thesis_5_2_1_arc",
                   XDG_DATA_HOME=str(tmp_path / "data"))  # fmt: skip
        models = tmp_path / "data" / "followbot" / "models"  # vision_verify's files.folder
        client = ["--robot", robot, "--mode", "client", "--connect", endpoint]
        logs: dict[str, Path] = {}
        procs: dict[str, subprocess.Popen] = {}

        def start(name: str, host, *args: str, python: tuple[str, ...] = ("-m", "followbot")):
            logs[name] = tmp_path / f"{name}.log"
            with logs[name].open("w") as fh:
                procs[name] = subprocess.Popen(
                    host.argv(sys.executable, *python, *args), stdout=fh,
                    stderr=subprocess.STDOUT, env=env, cwd=tmp_path,
                )  # fmt: skip
            return procs[name]

        def finish(name: str, timeout: float = 30.0) -> int:
            return procs[name].wait(timeout)

        def log(name: str) -> str:
            return logs[name].read_text()

        secure = str(REPO / "compose" / "split_secure.yaml")
        try:
            start("robot", bot, "up", secure, "--host", "robot", "--log-dir", str(tmp_path / "r"))
            start("offboard", off, "up", secure, "--host", "offboard",
                  "--log-dir", str(tmp_path / "o"))  # fmt: skip
            # (1) no certificate of this deployment: refused, whichever way it tries
            no_tls = json.dumps({"transport": {"link": {"tls": {
                "root_ca_certificate": str(certs / "ca.pem")}}}})  # fmt: skip
            (tmp_path / "ca_only.json5").write_text(no_tls)
            quick = ["--set", "zenoh.connect_timeout_s=3", "--duration", "2"]
            start("plain", off, "run", "monitor", "--robot", robot, "--mode", "client",
                  "--connect", f"tcp/{bot.address}:{port}", *quick)  # fmt: skip
            start("no_cert", off, "run", "monitor", *client, "--zenoh-config",
                  str(tmp_path / "ca_only.json5"), *quick)  # fmt: skip
            start("other_ca", off, "run", "monitor", *client, "--identity",
                  str(other / "operator"), *quick)  # fmt: skip
            deadline = time.monotonic() + 45
            while "target model 1 built" not in log("offboard"):
                assert time.monotonic() < deadline, log("offboard") + log("robot")
                time.sleep(0.25)
            start("record", bot, "record", "tracking/target", "control/cmd_vel",
                  "perception/target_command", "-o", str(tmp_path / "run.mcap"),
                  *client, "--identity", str(certs / "operator"))  # fmt: skip
            time.sleep(1.0)
            # (2) a valid certificate, the wrong identity
            evil, good = models / "evil.model", models / "good.model"
            vision_id = ["--identity", str(certs / "vision_verify")]
            start("attacker", off, evil.name, *client, *vision_id, python=("-c", ATTACKER))
            assert finish("attacker") == 0, log("attacker")
            start("attacker_cli", off, "target", "save", "--path", evil.name, *client, *vision_id)
            finish("attacker_cli")
            # the operator's identity may
            start("operator", off, "target", "save", "--path", good.name, *client,
                  "--identity", str(certs / "operator"))  # fmt: skip
            assert finish("operator") == 0, log("operator")
            deadline = time.monotonic() + 10
            while not good.exists() and time.monotonic() < deadline:
                time.sleep(0.1)
            procs["record"].send_signal(signal.SIGINT)
            assert finish("record") == 0, log("record")
            for name in ("plain", "no_cert", "other_ca"):
                assert finish(name, 15) == 1, f"{name} got in:\n{log(name)}"
        finally:
            for name in ("offboard", "robot"):
                if name in procs and procs[name].poll() is None:
                    procs[name].send_signal(signal.SIGINT)
            for p in procs.values():
                try:
                    p.wait(15)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()

    vision_log = (tmp_path / "o" / "vision_verify.log").read_text()
    # (2) the intruder was in (it read the track) but its commands reached nobody
    assert "attacker read" in log("attacker")
    read = int(log("attacker").split("attacker read ")[1].split()[0])
    assert read > 0, log("attacker")
    messages: dict[str, list] = {}
    for _t, topic, m in open_recording(tmp_path / "run.mcap").messages():
        messages.setdefault(topic, []).append(m)
    commands = messages.get("control/cmd_vel", [])
    assert commands and not [c for c in commands if c.reason == "attacker"]
    assert all(c.angular_radps != 1.234 for c in commands)
    assert [c.path for c in messages.get("perception/target_command", [])] == [good.name]
    assert good.exists() and not evil.exists(), vision_log
    assert f"saved to {good}" in vision_log and evil.name not in vision_log
    # (3) the robot followed, with vision from the other machine
    targets = messages.get("tracking/target", [])
    assert len(targets) > 20
    assert sum(t.status == "tracking" for t in targets) > 0.8 * len(targets)
    assert sum("vision" in t.sources for t in targets) > 0.5 * len(targets)
    assert any(abs(c.linear_mps) > 0 or abs(c.angular_radps) > 0 for c in commands)
