"""The remote command gate's bound on set_force: the configured contact-force limit."""

from __future__ import annotations

import math

import pytest

from controller.config import load_config
from controller.monitoring.command_gate import decide_command
from controller.shell.service import publisher_settings


@pytest.mark.parametrize("value", [1e9, 60.0, 60.000001, math.inf, math.nan, 0.0, -1.0, -math.inf])
def test_set_force_outside_zero_to_the_contact_force_limit_is_refused_naming_the_limit(value):
    decision = decide_command("set_force", value, True, 60.0)
    assert not decision.accepted and not decision.forward
    assert "safety.max_contact_force_n = 60 N" in decision.message


@pytest.mark.parametrize("value", [1e-3, 10.0, 59.9])
def test_set_force_below_the_limit_is_forwarded_to_the_law(value):
    assert decide_command("set_force", value, True, 60.0).forward


def test_the_bound_is_the_configured_limit_not_a_constant():
    settings = publisher_settings(load_config(overrides={"safety.max_contact_force_n": 25.0}))
    assert settings.max_contact_force_n == 25.0
    assert not decide_command("set_force", 30.0, True, settings.max_contact_force_n).accepted
    assert decide_command(
        "set_force", 30.0, True, publisher_settings(load_config()).max_contact_force_n
    ).accepted


def test_the_other_gated_commands_ignore_the_value():
    for name in ("pause", "resume", "reset"):
        assert decide_command(name, 1e9, True, 60.0).forward
