"""The secured deployment's files, read (no router): the role table of docs/operations.md
section 2 and the access-control policy of both router files allow exactly the same, the
two routers carry one policy, every shipped client file gives up on a router within
seconds, and make-certs.sh names each role in its certificate and password."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import pytest
import zenoh
from routers import DEPLOY, ROOT
from secure_kit import ROLES, SECURE, VARIANTS, make_certs

# a verb of the table -> the (flow, message) pairs of the router's rules it stands for
VERBS = {
    "put": {("ingress", "put"), ("ingress", "delete")},
    "receive": {("ingress", "declare_subscriber"), ("egress", "put"), ("egress", "delete")},
    "query": {("ingress", "query"), ("egress", "reply")},
    "answer": {("ingress", "declare_queryable"), ("ingress", "reply"), ("egress", "query")},
    "token": {("ingress", "liveliness_token")},
    "watch": {("ingress", "declare_liveliness_subscriber"), ("ingress", "liveliness_query"),
              ("egress", "liveliness_token"), ("egress", "reply")},
    "listeners": {("egress", "declare_subscriber")},
}
Grant = tuple[str, str, str]  # (flow, message, key expression)


def acl(variant: str) -> dict:
    """The router file's access_control, as Zenoh itself reads the json5."""
    conf = zenoh.Config.from_file(str(SECURE / variant / "router.json5"))
    return json.loads(conf.get_json("access_control"))


def router_grants(variant: str) -> dict[str, set[Grant]]:
    """Certificate CN / user -> every (flow, message, key) its policies allow."""
    a = acl(variant)
    assert a["enabled"] is True and a["default_permission"] == "deny"
    rules = {r["id"]: r for r in a["rules"]}
    assert all(r["permission"] == "allow" for r in rules.values())
    names = {s["id"]: s.get("cert_common_names") or s.get("usernames") for s in a["subjects"]}
    out: dict[str, set[Grant]] = {}
    for p in a["policies"]:
        for subject in p["subjects"]:
            (name,) = names[subject]
            out.setdefault(name, set()).update(
                (f, m, k) for r in p["rules"] for f in rules[r]["flows"]
                for m in rules[r]["messages"] for k in rules[r]["key_exprs"])
    return out


def table_grants() -> dict[str, set[Grant]]:
    """Certificate CN / user -> every (flow, message, key) the role table of
    docs/operations.md section 2 gives it."""
    text = (ROOT / "docs" / "operations.md").read_text()
    section = text[text.index("## 2. Running it secured"):text.index("## 3.")]
    lines = section.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith("| key (under `track/`)"))
    rows = []
    for ln in lines[start:]:
        if not ln.startswith("|"):
            break  # the table ends at its first line that is not a row
        rows.append([c.strip() for c in ln.strip().strip("|").split("|")])
    header, body = rows[0], rows[2:]
    cns = [re.search(r"\(`([^`]+)`\)", h).group(1) for h in header[1:]]
    assert len(body) >= 10 and all(len(r) == len(header) for r in body), body
    out: dict[str, set[Grant]] = {cn: set() for cn in cns}
    for row in body:
        key = "track/" + row[0].strip("`")
        for cn, cell in zip(cns, row[1:], strict=True):
            for verb in (v.strip() for v in cell.split(",") if v.strip() not in ("—", "")):
                out[cn] |= {(f, m, key) for f, m in VERBS[verb]}
    return out


def covered(grant: Grant, by: set[Grant]) -> bool:
    """Whether a grant of the same flow and message on an including key is in `by`."""
    f, m, k = grant
    return any(f == g[0] and m == g[1] and zenoh.KeyExpr(g[2]).includes(zenoh.KeyExpr(k))
               for g in by)


@pytest.mark.parametrize("variant", VARIANTS)
def test_the_role_table_and_the_router_allow_the_same(variant):
    router, table = router_grants(variant), table_grants()
    assert set(router) == set(table) == {cn for cn, _ in ROLES.values()}
    for cn in table:
        missing = sorted(g for g in table[cn] if not covered(g, router[cn]))
        extra = sorted(g for g in router[cn] if not covered(g, table[cn]))
        assert not missing, f"{cn}: the table allows, the router does not: {missing}"
        assert not extra, f"{cn}: the router allows, the table does not: {extra}"


def test_the_promises_of_the_table():
    """What the product promises each role (docs/protocol.md section 2, the clients)."""
    t = table_grants()

    def may(cn: str, verb: str, key: str) -> bool:
        return all(covered((f, m, f"track/{key}"), t[cn]) for f, m in VERBS[verb])

    viewer, tracker, feed = "track-viewer", "track-service", "track-feed"
    assert all(may(viewer, "receive", k) for k in ("frame", "display/x", "tracks/x",
                                                    "states", "errors/s", "meas/s/x"))
    assert all(may(viewer, "query", k) for k in ("frame", "display/x", "tracks/x", "status"))
    assert may(tracker, "listeners", "frame") and may(tracker, "listeners", "**")
    assert all(may(feed, "put", k) for k in ("meas/s/x", "scan/s", "plots/s", "clock",
                                              "truth/x"))
    assert may(feed, "query", "status") and may(feed, "watch", "alive/tracker/x")
    assert not any(may(viewer, "put", k) for k in ("meas/s/x", "clock", "frame"))
    assert not any(may(feed, "put", k) for k in ("frame", "display/x", "tracks/x"))
    assert not may(tracker, "put", "meas/s/x")
    assert may("track-intercept", "put", "display/interceptor-x")
    assert not may("track-intercept", "put", "display/x")


def test_both_routers_carry_the_same_policy():
    """The two variants differ in how clients prove who they are, not in what each
    role may do."""
    def policy(variant: str) -> tuple:
        a = acl(variant)
        return a["enabled"], a["default_permission"], a["rules"], a["policies"], \
            [s["id"] for s in a["subjects"]]
    assert policy("mtls") == policy("usrpwd")
    assert router_grants("mtls") == router_grants("usrpwd")


CLIENT_FILES = sorted(p for p in DEPLOY.rglob("*.json5") if "router" not in p.name)


@pytest.mark.parametrize("path", CLIENT_FILES, ids=lambda p: str(p.relative_to(DEPLOY)))
def test_every_client_file_gives_up_on_a_router_within_seconds(path: Path):
    conf = zenoh.Config.from_file(str(path))
    ms = json.loads(conf.get_json("connect/timeout_ms"))
    assert isinstance(ms, int) and 0 <= ms <= 5000, ms  # then one line names the cause


@pytest.mark.parametrize("variant", VARIANTS)
def test_each_client_file_proves_its_role(variant):
    for cn, name in ROLES.values():
        conf = zenoh.Config.from_file(str(SECURE / variant / name))
        assert json.loads(conf.get_json("mode")) == "client"
        assert json.loads(conf.get_json("connect/endpoints")) == ["tls/router:7447"]
        tls = json.loads(conf.get_json("transport/link/tls"))
        assert tls["root_ca_certificate"] == "/deploy/secure/certs/ca.pem"
        if variant == "mtls":
            assert tls["enable_mtls"] is True
            assert tls["connect_certificate"] == f"/deploy/secure/certs/{cn}.pem"
            assert tls["connect_private_key"] == f"/deploy/secure/certs/{cn}-key.pem"
        else:
            auth = json.loads(conf.get_json("transport/auth/usrpwd"))
            assert auth["user"] == cn and auth["password"] == "CHANGE-ME"


def test_make_certs_names_each_role_in_its_certificate(tmp_path):
    certs = make_certs(tmp_path / "c")
    roles = [cn for cn, _ in ROLES.values()]
    for role in roles:
        subject = subprocess.run(["openssl", "x509", "-in", str(certs / f"{role}.pem"),
                                  "-noout", "-subject"], capture_output=True, text=True,
                                 check=True).stdout
        assert f"CN = {role}" in subject or f"CN={role}" in subject
        assert len((certs / f"{role}.password").read_text()) == 32
    lines = (certs / "credentials.txt").read_text().splitlines()
    assert sorted(ln.split(":")[0] for ln in lines) == sorted(roles)
    assert not (certs / "ca.srl").exists()
