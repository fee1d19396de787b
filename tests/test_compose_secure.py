"""docker-compose.secure.yml: the same deployment as docker-compose.yml with the secured
configs of deploy/secure/mtls/, each container with the config of its role. Checked
statically (no container engine here); tests/test_security.py runs these config files."""

from __future__ import annotations

import json
from pathlib import Path

import zenoh
from test_compose import ROOT, compose, config_arg, host_path, load_subset, unescape

SECURE = ROOT / "docker-compose.secure.yml"
ROLE = {"router": "router", "shard-a": "service", "shard-b": "service", "feed": "feed",
        "display": "viewer"}
CN = {"service": "track-service", "feed": "track-feed", "viewer": "track-viewer"}


def secured() -> dict:
    return load_subset(SECURE.read_text())["services"]


def test_secure_compose_is_the_plain_one_with_secured_configs():
    plain, secure = compose(), secured()
    assert set(secure) == set(plain) == set(ROLE)
    for name, svc in secure.items():
        cmd, base = list(svc["command"]), list(plain[name]["command"])
        conf = config_arg(cmd)
        assert conf == f"/deploy/secure/mtls/{ROLE[name]}.json5", (name, conf)
        i = cmd.index(conf)
        assert cmd[:i] + cmd[i + 1:] == base[:i] + base[i + 1:], name  # all else the same
        assert {k: v for k, v in svc.items() if k != "command"} == \
            {k: v for k, v in plain[name].items() if k != "command"}, name


def test_each_container_proves_its_role_to_the_router():
    secure = secured()
    router = zenoh.Config.from_file(str(host_path(secure["router"],
                                                  config_arg(secure["router"]["command"]))))
    acl = json.loads(router.get_json("access_control"))
    assert acl["enabled"] and acl["default_permission"] == "deny"
    names = {s["id"]: s["cert_common_names"] for s in acl["subjects"]}
    assert json.loads(router.get_json("transport/link/tls/enable_mtls")) is True
    assert json.loads(router.get_json("transport/link/protocols")) == ["tls"]
    assert json.loads(router.get_json("listen/endpoints")) == ["tls/0.0.0.0:7447"]
    certs = host_path(secure["router"], "/deploy/secure/certs/ca.pem").parent
    assert certs == (ROOT / "deploy" / "secure" / "certs").resolve()
    assert "deploy/secure/certs/" in (ROOT / ".gitignore").read_text().splitlines()
    for name, svc in secure.items():
        if name == "router":
            continue
        conf = zenoh.Config.from_file(str(host_path(svc, config_arg(
            [unescape(a) for a in svc["command"]]))))
        assert json.loads(conf.get_json("mode")) == "client"
        assert json.loads(conf.get_json("connect/endpoints")) == ["tls/router:7447"]
        tls = json.loads(conf.get_json("transport/link/tls"))
        cn = CN[ROLE[name]]
        assert tls["enable_mtls"] is True
        assert tls["connect_certificate"] == f"/deploy/secure/certs/{cn}.pem"
        assert Path(host_path(svc, tls["connect_private_key"])).parent == certs
        role = {"service": "tracker", "feed": "feed", "viewer": "viewer"}[ROLE[name]]
        assert names[role] == [cn], (name, names)
