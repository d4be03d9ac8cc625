"""docker-compose.yml is generated from the launcher's service list and must stay in sync with it.

No Docker engine runs here, so the compose file is validated by docker-compose's own `config`
(Debian package, installed by scripts/setup.sh) and the router config by Zenoh's own parser.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest
import yaml
import zenoh

from coplane.fleet import COMPOSE_RECORDING, COMPOSE_ROUTER, compose_document, fleet_of, fleet_services
from coplane.fleet.compose import router_config_text
from coplane.sim.generate import bundled_default_path

REPO = Path(__file__).resolve().parents[2]


def _committed() -> dict:
    return yaml.safe_load((REPO / "docker-compose.yml").read_text())


def test_committed_compose_is_the_generated_one() -> None:
    fleet, vehicles = fleet_of(bundled_default_path())
    assert _committed() == compose_document(vehicles), "run `coplane compose` and commit docker-compose.yml"
    router = (REPO / "deploy" / "zenoh" / "router.json5").read_text()
    assert router == router_config_text(vehicles, fleet), (
        "run `coplane compose` and commit deploy/zenoh/router.json5"
    )


def test_compose_is_secure_and_local_by_default() -> None:
    """TLS router with ACL, one identity per service, certificates from the one-shot service, ports
    published on 127.0.0.1 unless COPLANE_BIND says otherwise."""
    doc = _committed()
    services = doc["services"]
    assert services["zenoh-router"]["ports"] == ["${COPLANE_BIND:-127.0.0.1}:7447:7447"]
    assert services["api"]["ports"] == ["${COPLANE_BIND:-127.0.0.1}:8000:8000"]
    assert services["certs"]["command"][:3] == ["coplane", "certs", "init"]
    _, vehicles = fleet_of(bundled_default_path())
    identities = {
        n: s["environment"]["COPLANE_BUS_IDENTITY"] for n, s in services.items() if "environment" in s
    }
    assert identities == {"fusion-server": "fusion", "api": "api"} | {
        f"agent-{v}": f"vehicle-{v}" for v in vehicles
    }
    for name in identities:
        assert services[name]["depends_on"]["certs"] == {"condition": "service_completed_successfully"}
        assert "coplane-certs:/certs:ro" in services[name]["volumes"]
        assert COMPOSE_ROUTER in services[name]["command"][services[name]["command"].index("--connect") + 1]
    assert COMPOSE_ROUTER.startswith("tls/")
    cfg = zenoh.Config.from_file(str(REPO / "deploy" / "zenoh" / "router.json5"))
    assert cfg.get_json("access_control/default_permission") == '"deny"'
    assert cfg.get_json("transport/link/tls/enable_mtls") == "true"
    assert cfg.get_json("listen/endpoints") == '["tls/[::]:7447"]'


def test_solution_logs_live_on_a_named_volume() -> None:
    """The fusion server and the API keep their solution logs (docs/reliability/durability.md) on
    the `coplane-state` volume, so a container restart or `docker compose down/up` resumes."""
    doc = _committed()
    assert "coplane-state" in doc["volumes"]
    for name in ("fusion-server", "api"):
        svc = doc["services"][name]
        assert svc["environment"]["COPLANE_STATE_DIR"] == "/state"
        assert "coplane-state:/state" in svc["volumes"]
    dockerfile = (REPO / "Dockerfile").read_text()
    assert "chown 65534:65534 /state" in dockerfile and "ENV COPLANE_STATE_DIR=/state" in dockerfile


def test_compose_starts_what_the_launcher_starts() -> None:
    """Same services, same modules, same arguments up to the recording path and router address."""
    _, vehicles = fleet_of(bundled_default_path())
    launcher = fleet_services(
        bundled_default_path(), "pc", "realtime", 1.0, "tls/127.0.0.1:7447", vehicles, api=True
    )
    compose = _committed()["services"]
    assert set(compose) == {"zenoh-router", "certs"} | {s.name for s in launcher}
    assert {f"agent-{v}" for v in vehicles} <= set(compose)

    def norm(args: list[str]) -> list[str]:
        out = [a.replace(str(bundled_default_path()), "REC").replace(COMPOSE_RECORDING, "REC") for a in args]
        return [a.replace("tls/127.0.0.1:7447", "ROUTER").replace(COMPOSE_ROUTER, "ROUTER") for a in out]

    for spec in launcher:
        cmd = compose[spec.name]["command"]
        assert cmd[:3] == ["python", "-m", spec.module]
        extra = cmd[3 + len(spec.args) :]
        assert norm(cmd[3 : 3 + len(spec.args)]) == norm(spec.args)
        assert extra in ([], ["--host", "0.0.0.0"])
    assert all("healthcheck" in compose[s.name] for s in launcher)
    assert all(compose[s.name]["environment"]["COPLANE_BUS_IDENTITY"] == s.identity for s in launcher)


def test_compose_file_validates_with_docker_compose() -> None:
    exe = shutil.which("docker-compose")
    if exe is None:
        pytest.fail("docker-compose not installed (scripts/setup.sh installs Debian's docker-compose)")
    r = subprocess.run(
        [exe, "-f", str(REPO / "docker-compose.yml"), "config", "-q"],
        capture_output=True,
        text=True,
        cwd=REPO,
    )
    assert r.returncode == 0, r.stderr


def test_router_config_parses_with_zenoh() -> None:
    cfg = zenoh.Config.from_file(str(REPO / "deploy" / "zenoh" / "router.json5"))
    assert '"router"' in cfg.get_json("mode")


def test_compose_scales_to_a_router_mesh_and_several_servers(tmp_path: Path) -> None:
    """`coplane compose --servers 2 --routers 3` (issue 16): the further routers connect to the
    first over mutual TLS with the same ACL, the router certificate names every router, the
    servers share the fleet by region and keep their logs on the state volume, the agents take
    the routers in turn; docker-compose and Zenoh accept what is written."""
    from coplane.fleet import write_compose

    out = tmp_path / "docker-compose.yml"
    write_compose(out, servers=2, routers=3)
    doc = yaml.safe_load(out.read_text())
    svc = doc["services"]
    routers = ["zenoh-router", "zenoh-router-2", "zenoh-router-3"]
    assert all(r in svc for r in routers) and "fusion-server" not in svc
    certs = svc["certs"]["command"]
    assert certs[certs.index("--dns") + 1] == "zenoh-router-2,zenoh-router-3"
    assert certs[certs.index("--servers") + 1] == "s1,s2"  # each server its own identity
    assert "ports" in svc["zenoh-router"] and "ports" not in svc["zenoh-router-2"]
    for r in routers[1:]:
        assert (
            svc[r]["volumes"][0]
            == f"./deploy/zenoh/{r.removeprefix('zenoh-')}.json5:/etc/zenoh/router.json5:ro"
        )
        cfg = zenoh.Config.from_file(str(tmp_path / "deploy" / "zenoh" / f"{r.removeprefix('zenoh-')}.json5"))
        assert "tls/zenoh-router:7447" in cfg.get_json("connect/endpoints")
        assert "connect_certificate" in cfg.get_json("transport/link/tls")
        assert cfg.get_json("access_control") == zenoh.Config.from_file(
            str(tmp_path / "deploy" / "zenoh" / "router.json5")
        ).get_json("access_control")
    acl = zenoh.Config.from_file(str(tmp_path / "deploy" / "zenoh" / "router.json5")).get_json(
        "access_control"
    )
    for k in (1, 2):
        s = svc[f"fusion-server-{k}"]
        assert "--regions" in s["command"] and s["environment"]["COPLANE_STATE_DIR"] == "/state"
        assert all(r in s["depends_on"] for r in routers)
        assert s["command"][s["command"].index("--server_id") + 1] == f"s{k}"
        assert s["environment"]["COPLANE_BUS_IDENTITY"] == f"fusion-s{k}"
        assert f'"fusion-s{k}"' in acl  # the routers know the identity
    connects = {
        svc[f"agent-{v}"]["command"][svc[f"agent-{v}"]["command"].index("--connect") + 1]
        for v in ("u1", "u2", "u3", "u4")
    }
    assert len(connects) > 1  # the agents are spread over the mesh
    exe = shutil.which("docker-compose")
    if exe is None:
        pytest.fail("docker-compose not installed (scripts/setup.sh installs Debian's docker-compose)")
    r = subprocess.run([exe, "-f", str(out), "config", "-q"], capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 0, r.stderr


def test_compose_passes_cluster_workers_to_every_server() -> None:
    """`coplane compose --cluster-workers 2`: each server solves its clusters on 2 processes; the
    default file starts none (the committed one is checked above)."""
    _, vehicles = fleet_of(bundled_default_path())
    for servers in (1, 2):
        doc = compose_document(vehicles, servers=servers, cluster_workers=2)
        fusion = [s for name, s in doc["services"].items() if name.startswith("fusion-server")]
        assert len(fusion) == servers
        for s in fusion:
            cmd = s["command"]
            assert cmd[cmd.index("--cluster_workers") + 1] == "2"
    assert all(
        "--cluster_workers" not in s.get("command", [])
        for s in compose_document(vehicles)["services"].values()
    )


def test_the_launcher_passes_the_map_setting_on(tmp_path: Path) -> None:
    """`--map none` reaches the fusion servers (their own default is `auto`); `auto` is left to
    them; a file is given to every server, each of which keeps its replica beside it."""
    _, vehicles = fleet_of(bundled_default_path())

    def map_args(map_path: Path | str | None, servers: int = 1) -> list[list[str]]:
        specs = fleet_services(
            bundled_default_path(), "pc", "lockstep", 1.0, "tcp/127.0.0.1:7447", vehicles, False,
            map_path=map_path, servers=servers,
        )  # fmt: skip
        out = []
        for s in specs:
            if s.name.startswith("fusion-server"):
                out.append(
                    s.args[s.args.index("--map") : s.args.index("--map") + 2] if "--map" in s.args else []
                )
        return out

    assert map_args(None) == [["--map", "none"]]
    assert map_args("auto") == [[]]
    assert map_args(tmp_path / "m.sqlite", servers=2) == [["--map", str(tmp_path / "m.sqlite")]] * 2
