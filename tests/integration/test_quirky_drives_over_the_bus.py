"""Quirky drives over the udp_multicast bus, as a user meets them: the simulator as its own process
with sim.drive.quirks, the controller (``cheope run``) handling them through configuration alone,
refusing at start (exit 2, one line naming the drive and what it does) without it, and ``cheope nodes``
showing the bus as a commissioning tool would."""

from __future__ import annotations

import json
import os
import random
import subprocess
import sys

import pytest
from busy_machine import TOLERANT, how_the_run_ended

from controller.shell.demo import simulator_process
from drivers.bus import parse_bus_spec

pytestmark = pytest.mark.integration
CHEOPE = [sys.executable, "-m", "controller"]


def _cheope(*args: str, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*CHEOPE, *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


def _sets(overrides: dict[str, str]) -> list[str]:
    return [a for k, v in overrides.items() for a in ("--set", f"{k}={v}")]


# A drive that boots late and needs the SDO retried, one that needs an NMT reset to boot, one
# supervised by node guarding, one with a fixed mapping: handled together by configuration alone.
QUIRKS = {
    "sim.drive.quirks": '["late_boot:1", "sdo_aborts:1", "needs_nmt_reset:2", "guarding_only:3", "fixed_mapping:3"]',
    "sim.quirk.boot_delay_s": "1.5",
    "task.path.laps": "0.25",
}
HANDLING = {
    "loop.boot_timeout_s": "3.0",
    "loop.boot_retries": "1",
    "loop.sdo_retries": "1",
    "node": '[{node_id = 3, supervision = "guarding", pdo_mapping = "read"}]',
}


def test_quirky_drives_run_the_path_to_done_by_configuration_and_are_refused_without_it():
    spec = parse_bus_spec("udp_multicast", udp_port=random.SystemRandom().randint(45000, 47999))
    port = ["--udp-port", str(spec.udp_port)]
    with simulator_process(spec, None, [f"{k}={v}" for k, v in QUIRKS.items()]):
        r = _cheope("run", "--json", *port, *_sets({**QUIRKS, **HANDLING}), *TOLERANT)
        assert r.returncode == 0, how_the_run_ended(r.stdout, r.stderr)
        summary = json.loads(r.stdout)
        assert summary["final_mode"] == "DONE"
        notes = " | ".join(summary["node_setup_notes"])
        assert "node 2: no SDO answer within 3.0 s: NMT reset node sent" in notes
        assert "SDO transfer(s) repeated" in notes and "TPDO1 read from the drive" in notes
        nodes = _cheope("nodes", "--json", *port)
        assert nodes.returncode == 0, nodes.stderr[-2000:]
        scanned = {n["node_id"]: n for n in json.loads(nodes.stdout)["nodes"]}
        assert set(scanned) == {1, 2, 3, 16}
        assert scanned[3]["supervision"] == "guarding" and scanned[1]["supervision"] == "heartbeat"
        assert scanned[1]["power_state"] == "READY_TO_SWITCH_ON"  # the run ended by shutting them down
        # the same drives without that configuration: refused at start, naming the drive and the habit
        refused = _cheope(
            "run",
            "--json",
            *port,
            *_sets(
                {**QUIRKS, "loop.boot_timeout_s": "3.0", "loop.sdo_retries": "1", "loop.boot_retries": "1"}
            ),
            *TOLERANT,
        )
    assert refused.returncode == 2, refused.stdout + refused.stderr
    assert "node 3: writing 0x1017sub0 = 0x64 refused" in refused.stderr
    assert 'a drive without heartbeat: actuators.supervision = "guarding"' in refused.stderr
    assert "Traceback" not in refused.stderr and "ERROR" not in refused.stderr
