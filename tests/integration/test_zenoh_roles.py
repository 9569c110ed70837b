"""Roles over Zenoh, as shipped (issue 38, item 3): controller/configs/zenoh/*.json5 with generated
certificates (tests/tls_certificates.py).

The files are used as written but for two substitutions: the certificates' directory
(``/etc/cheope/tls/`` -> the test's) and the controller's listen endpoint (``tls/0.0.0.0:7448`` ->
``tls/127.0.0.1:<free port>``: a test listens on loopback only). The controller is the publisher
every controller runs (controller/monitoring/publisher.py), in this process; the clients are the
``cheope`` tools in processes of their own, configured with the viewer's or the operator's file.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from tls_certificates import write_certificates

from controller.assembly import build_law
from controller.config import load_config
from controller.core.cycle_data import CycleInputs, CycleOutputs, DriveFeedback
from controller.core.ports import CycleTiming
from controller.monitoring.commands import tool_session
from controller.monitoring.publisher import MonitorPublisher
from controller.monitoring.zenoh_session import client_settings, free_loopback_port
from controller.shell.service import publisher_settings

pytestmark = pytest.mark.integration

SHIPPED = Path(__file__).resolve().parents[2] / "controller" / "configs" / "zenoh"


def _env() -> dict[str, str]:
    """The environment of the processes a test starts, read when it starts them: the session's
    temporary XDG directories (tests/conftest.py) are set after this module is imported."""
    return {**os.environ, "PYTHONUNBUFFERED": "1"}


def _shipped(name: str, tls_dir: Path, port: int) -> Path:
    text = (SHIPPED / f"{name}.json5").read_text()
    assert "/etc/cheope/tls/" in text
    text = text.replace("/etc/cheope/tls/", f"{tls_dir}/").replace(
        "tls/0.0.0.0:7448", f"tls/127.0.0.1:{port}"
    )
    out = tls_dir / f"{name}.json5"
    out.write_text(text)
    return out


@contextmanager
def _controller(tmp_path: Path) -> Iterator[tuple[MonitorPublisher, threading.Event, Path, str]]:
    tls = tmp_path / "tls"
    write_certificates(tls)
    port = free_loopback_port()
    cfg = load_config(
        overrides={
            "monitoring.config_file": str(_shipped("controller-mtls-acl", tls, port)),
            "monitoring.robot_id": "r1",
            "monitoring.allow_remote_commands": True,
        }
    )
    stop = threading.Event()
    with MonitorPublisher(publisher_settings(cfg), stop, task_name="path") as pub:
        yield pub, stop, tls, f"tls/localhost:{port}"  # the certificate names localhost


def _cheope(endpoint: str, config: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [
            sys.executable,
            "-m",
            "controller",
            *args,
            "--zenoh-connect",
            endpoint,
            "--zenoh-config",
            str(config),
        ],
        check=False,
        capture_output=True,
        text=True,
        env=_env(),
        timeout=60,
    )


def test_a_viewer_watches_and_asks_status_an_operator_also_commands(tmp_path: Path) -> None:
    with _controller(tmp_path) as (pub, stop, tls, endpoint):
        port = int(endpoint.rsplit(":", 1)[1])
        viewer, operator = _shipped("viewer", tls, port), _shipped("operator", tls, port)
        for client in (viewer, operator):
            status = _cheope(endpoint, client, "status", "--robot-id", "r1")
            assert status.returncode == 0, status.stderr
            # the endpoint the session listens on, from the file (was the unused loopback default)
            assert f"listening on        tls/127.0.0.1:{port}\n" in status.stdout
            listed = _cheope(endpoint, client, "list")
            assert listed.returncode == 0 and "r1" in listed.stdout, listed.stderr

        refused = _cheope(endpoint, viewer, "command", "pause", "--robot-id", "r1", "--timeout", "3")
        assert refused.returncode == 2 and "no controller answered on cheope/r1/command" in refused.stderr
        refused = _cheope(endpoint, viewer, "stop", "--robot-id", "r1", "--timeout", "3")
        assert refused.returncode == 2 and not stop.is_set()
        assert pub.commands() is None and pub.commands_accepted == pub.commands_refused == 0

        accepted = _cheope(endpoint, operator, "command", "pause", "--robot-id", "r1")
        assert accepted.returncode == 0 and accepted.stdout.startswith("accepted by r1"), accepted.stderr
        assert pub.commands() == ("pause", 0.0)
        accepted = _cheope(endpoint, operator, "stop", "--robot-id", "r1")
        assert accepted.returncode == 0 and stop.is_set(), accepted.stderr


def test_the_viewer_receives_the_state(tmp_path: Path) -> None:
    with _controller(tmp_path) as (pub, _, tls, endpoint):
        viewer = _shipped("viewer", tls, int(endpoint.rsplit(":", 1)[1]))
        cfg = load_config()
        state = build_law(cfg).initial_state()
        inputs = CycleInputs(drives=(DriveFeedback(0x1237, 0.55, True),) * 3)
        outputs = CycleOutputs((0x0F,) * 3, (0.55,) * 3)
        received: list[str] = []
        with tool_session(client_settings((endpoint,), str(viewer))) as session:
            session.declare_subscriber("cheope/r1/state", lambda s: received.append(str(s.key_expr)))
            deadline, k = time.monotonic() + 30.0, 0
            while not received and time.monotonic() < deadline:
                pub.on_cycle(k, k * 0.0025, inputs, state, outputs, (), CycleTiming(1e-5, 1e-4))
                k += 20
                time.sleep(0.01)
        assert received and received[0] == "cheope/r1/state"


def test_a_client_without_a_certificate_of_the_ca_is_turned_away(tmp_path: Path) -> None:
    with _controller(tmp_path) as (pub, stop, tls, endpoint):
        port = int(endpoint.rsplit(":", 1)[1])
        operator = _shipped("operator", tls, port).read_text()
        # the guide's former client settings: TLS without enable_mtls sends no certificate
        no_mtls = tls / "no-mtls.json5"
        no_mtls.write_text(operator.replace("enable_mtls: true", "enable_mtls: false"))
        # an operator's common name, signed by another CA
        stranger = tls / "stranger.json5"
        stranger.write_text(operator.replace(f"{tls}/operator", f"{tls}/stranger"))
        for client in (no_mtls, stranger):
            r = _cheope(endpoint, client, "stop", "--robot-id", "r1", "--timeout", "3")
            turned_away = ("Unable to connect" in r.stderr) or ("nothing answers at" in r.stderr)
            assert r.returncode == 2 and turned_away, r.stdout + r.stderr
        assert not stop.is_set() and pub.commands_accepted == 0
