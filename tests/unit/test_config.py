"""Configuration validation: every error names the key, the value and the reason."""

from __future__ import annotations

import pytest

from controller.config import CYCLE_KEYS_NOW_SECONDS, ConfigError, load_config, parse_override


def test_shipped_defaults_load(cfg):
    assert cfg.loop.rate_hz == 400.0
    assert cfg.robot.model("cheope").rod_length_m == 0.5
    assert cfg.period_s == pytest.approx(0.0025)


@pytest.mark.parametrize(
    "overrides,message",
    [
        ({"loop.rate_hz": -5}, r"loop.rate_hz = -5: must be >= 1.0"),
        ({"robot.cheope.rod_length_m": -1.0}, r"robot.cheope.rod_length_m = -1.0: must be > 0.0"),
        ({"robot.cheope.rod_length_m": "long"}, r"robot.cheope.rod_length_m = 'long': expected a number"),
        ({"loop.unknown_key": 1}, r"unknown key\(s\) unknown_key in \[loop\]"),
        ({"actuators.node_ids": [1, 1, 2]}, r"node ids must be distinct"),
        (
            {"robot.cheope.stroke_min_m": 0.9, "robot.cheope.stroke_max_m": 0.3},
            r"stroke_min_m = 0.9 must be <",
        ),
        # all masses at 0 ended a simulated demo in a ZeroDivisionError; a stiffness of 1e-300 N/m
        # made `cheope analyze` fail on a NaN after writing its plots (an outside tester's findings)
        (
            {"robot.cheope.mass.platform_kg": 0.0, "robot.cheope.mass.rod_pair_kg": 0.0},
            r"robot.cheope.mass.platform_kg = 0.0, robot.cheope.mass.slider_kg = 1.0, "
            r"robot.cheope.mass.rod_pair_kg = 0.0: the mass that moves with the tool \(translating_kg\) "
            r"is 0 kg: it must be more than 0 kg",
        ),
        (
            {"robot.cheope.mass.actuator_stiffness_n_m": 1e-300},
            r"robot.cheope.mass.actuator_stiffness_n_m = 1e-300: must be >= 1.0",
        ),
        (
            {"loop.max_missing_cycles": 2.5},
            r"loop.max_missing_cycles = 2.5: a whole number of cycles >= 1 was expected \(the key is "
            r"loop.max_missing_s now, in seconds\)",
        ),
        ({"loop.max_missing_s": 0}, r"loop.max_missing_s = 0: must be > 0"),
        ({"robot.kind": "hexapod"}, r"robot.kind = 'hexapod': must be one of"),
        ({"loop.rate_hz": float("nan")}, r"loop.rate_hz = nan: must be finite"),
        # keys without a range: a NaN there made every comparison with it false (the joint-swing
        # check never tripped with a neutral point of [0, nan, 0.5])
        (
            {"robot.cheope.joint_neutral_tcp_m": [0.0, float("nan"), 0.5]},
            r"robot.cheope.joint_neutral_tcp_m\[1\] = nan: must be finite",
        ),
        (
            {"sim.workpiece.centre_m": [float("inf"), 0.0]},
            r"sim.workpiece.centre_m\[0\] = inf: must be finite",
        ),
        ({"sim.sensor.bias_n": [0.0, 0.0, float("-inf")]}, r"sim.sensor.bias_n\[2\] = -inf: must be finite"),
        ({"sim.drive.limit_switches_m": [0.88, 0.32]}, r"negative switch must lie below the positive one"),
        ({"sim.sensor.seed": -1}, r"sim.sensor.seed = -1: must be >= 0"),  # numpy's own error named no key
        ({"recording.buffer_bytes": 4096}, r"recording.buffer_bytes = 4096: must be >= 65536"),
        ({"sim.drive.cogging_period_m": 0.0}, r"sim.drive.cogging_period_m = 0.0: must be > 0.0"),
        ({"sim.drive.cogging_force_n": -1.0}, r"sim.drive.cogging_force_n = -1.0: must be >= 0.0"),
        ({"sim.structure_inertial_load": 1}, r"sim.structure_inertial_load = 1: expected true or false"),
        (
            {"actuators.sync_watchdog_s": 0.03},  # 25 ms of extrapolation + 2 periods at 400 Hz is 30 ms
            r"actuators.sync_watchdog_s = 0.03 must exceed actuators.extrapolation_s = 0.025 by more than "
            r"two periods \(loop.rate_hz = 400.0\): the drives would quick-stop while they run on",
        ),
        ({"actuators.sync_watchdog_s": 70.0}, r"actuators.sync_watchdog_s = 70.0: must be <= 65.535"),
    ],
)
def test_invalid_values_are_named(overrides, message):
    with pytest.raises(ConfigError, match=message):
        load_config(overrides=overrides)


def test_a_node_list_not_one_per_actuator_is_named_when_the_robot_is_built():
    """Any length is a list (a robot may have 4 or 6 actuators); Cheope's 3 ask for 3."""
    from controller.assembly import build_law

    cfg = load_config(overrides={"actuators.node_ids": [1, 2]})
    with pytest.raises(
        ConfigError,
        match=r"actuators.node_ids = \[1, 2\]: 2 value\(s\) for the 3 actuators of robot.kind = 'cheope'",
    ):
        build_law(cfg)


@pytest.mark.parametrize(
    "overrides,message",
    [
        # an outside tester's, accepted on 44dbcbc
        ({"task.contour.force_setpoint_n": 80.0}, r"force_setpoint_n = 80 N < max_force_n = 40 N"),
        ({"task.contour.force_setpoint_n": 1.0}, r"contact_lost_force_n = 1 N < force_setpoint_n = 1 N"),
        ({"task.contour.contact_force_n": 500.0}, r"contact_force_n = 500 N < max_force_n, must hold"),
        ({"safety.contact.guarded_move_force_n": 1000.0}, r"guarded_move_force_n = 1000 N <= "),
        ({"safety.max_contact_force_n": 5.0}, r"safety.max_contact_force_n = 5 N must hold"),
        # an outside tester's: after a contact loss the tool coasted 88 mm off the part
        (
            {"task.contour.stop_deceleration_m_s2": 0.001},
            r"stop_deceleration_m_s2 = 0.001 m/s\^2: braking from the fastest contour speed \(0.06 m/s, "
            r".* coasts 1800.0 mm .*envelope_margin_m = 12 mm; at least 0.15 m/s\^2",
        ),
        # the exploring lap counts too
        (
            {
                "task.contour.lap_speeds_m_s": [0.02],
                "task.contour.explore_speed_m_s": 0.05,
                "task.contour.stop_deceleration_m_s2": 0.1,
            },
            r"fastest contour speed \(0.05 m/s.* coasts 12.5 mm",
        ),
    ],
)
def test_force_limits_out_of_order_are_refused_when_loaded(overrides, message):
    with pytest.raises(ConfigError, match=message):
        load_config(overrides={"task.kind": "contour", **overrides})


@pytest.mark.parametrize(
    "key,value,bound",
    [
        # an outside tester's: 68.9, 96 and 91.8 N on the 1 mm x 30 mm bump, within the old ranges
        ("force_kp_m_s_per_n", 0.005, "0.001"),
        ("force_kp_m_s_per_n", 0.01, "0.001"),
        ("force_ki_m_s2_per_n", 10.0, "0.01"),
        # the first steps past the bounds: 1.5e-3 lost contact 4 times in lap 1; 3e-2 stalled
        ("force_kp_m_s_per_n", 0.0015, "0.001"),
        ("force_ki_m_s2_per_n", 0.03, "0.01"),
    ],
)
def test_force_gains_past_what_tracks_the_bump_are_refused_naming_the_key_and_bound(key, value, bound):
    with pytest.raises(ConfigError, match=rf"task.contour.{key} = {value}: must be <= {bound}"):
        load_config(overrides={"task.kind": "contour", f"task.contour.{key}": value})


def test_force_gains_at_their_bounds_are_accepted():
    """Both at once tracked the bump to DONE at 21.9 N true (the limit 40 N)."""
    load_config(
        overrides={
            "task.kind": "contour",
            "task.contour.force_kp_m_s_per_n": 1e-3,
            "task.contour.force_ki_m_s2_per_n": 1e-2,
        }
    )


def test_a_stop_deceleration_that_keeps_the_coast_within_the_envelope_is_accepted():
    """0.06^2 / (2 x 0.15) = 12 mm: the envelope margin, just."""
    load_config(overrides={"task.kind": "contour", "task.contour.stop_deceleration_m_s2": 0.15})


@pytest.mark.parametrize(
    "overrides,message",
    [
        (
            {"task.contour.max_force_n": 80.0},
            r"max_force_n = 80 N: must be at most 50 N, safety.max_contact_force_n = 60 N less the 10 N",
        ),
        # an outside tester's: equal to the safety layer's, accepted (only above was refused)
        (
            {"task.contour.max_force_n": 60.0, "task.contour.search_speed_m_s": 0.005},
            r"max_force_n = 60 N: must be at most 50 N, .* before its retract takes hold",
        ),
        (
            {"task.contour.max_force_n": 50.5, "task.contour.search_speed_m_s": 0.005},
            r"max_force_n = 50.5 N: must be at most 50 N",
        ),
        (
            {"task.contour.lap_speeds_m_s": [0.02, 0.12]},
            r"lap_speeds_m_s: 0.12 m/s with max_normal_speed_m_s = 0.02 m/s is faster than "
            r"safety.contact.max_contact_speed_m_s = 0.1 m/s",
        ),
        (
            {"task.contour.approach_speed_m_s": 0.1, "safety.contact.max_contact_speed_m_s": 0.08},
            r"approach_speed_m_s: 0.1 m/s is faster than safety.contact.max_contact_speed_m_s = 0.08",
        ),
        (
            {"task.contour.contact_force_n": 30.0},
            r"contact_force_n = 30 N: the approach, a guarded move, is stopped at "
            r"safety.contact.guarded_move_force_n = 25 N first",
        ),
    ],
)
def test_a_contour_the_contact_guard_would_stop_at_once_is_refused_before_it_starts(overrides, message):
    """Checked against the safety section when the task is built, before the bus is opened: a lap
    faster than a move expecting contact may be was a quick stop in contact (29 N left pressed)."""
    from controller.assembly import build_law

    cfg = load_config(overrides={"task.kind": "contour", **overrides})
    with pytest.raises(ConfigError, match=message):
        build_law(cfg)


def test_a_task_limit_the_tasks_overshoot_keeps_below_the_safety_limit_is_accepted():
    from controller.assembly import build_law

    build_law(load_config(overrides={"task.kind": "contour", "task.contour.max_force_n": 50.0}))


def test_an_unknown_key_of_a_node_table_lists_the_keys_a_node_takes(tmp_path):
    """It listed the top level's (actuators, bus, loop, ...) for a key of ``[[node]]``."""
    p = tmp_path / "node.toml"
    p.write_text("[[node]]\nnode_id = 1\nfoo = 1\n")
    with pytest.raises(
        ConfigError, match=r"unknown key\(s\) foo in \[node\[0\]\]; known: boot_retries, .*node_id"
    ) as err:
        load_config(p)
    assert "actuators" not in str(err.value)


def test_missing_file_is_named(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "nope.toml")


def test_broken_toml_is_named(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("[loop\nrate_hz = 3")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(p)


def test_parse_override():
    assert parse_override("loop.rate_hz=1000") == ("loop.rate_hz", 1000)
    assert parse_override('bus.can="socketcan:vcan0"') == ("bus.can", "socketcan:vcan0")
    assert parse_override("bus.can=udp_multicast") == ("bus.can", "udp_multicast")
    assert parse_override("task.path.center_m=[0, 0, 0.45]") == ("task.path.center_m", [0, 0, 0.45])
    with pytest.raises(ConfigError, match="expected KEY=VALUE"):
        parse_override("loop.rate_hz")


@pytest.mark.parametrize(
    "text", ["loop.rate_hz=400\nloop.spin_us=-5", "bus.can=vcan0\r\nloop.rate_hz=5", "a\nb=1"]
)
def test_a_line_break_in_a_set_is_refused(text):
    """TOML read the first line and took the rest for keys of its own: ``loop.rate_hz=400<newline>
    loop.spin_us=-5`` set the rate, dropped the rest and exited 0 (an outside tester's finding)."""
    with pytest.raises(ConfigError, match=r"a line break in KEY=VALUE; give each key its own --set"):
        parse_override(text)


def test_a_set_with_a_line_break_ends_the_command_with_one_line(capsys, tmp_path):
    from controller.cli import main

    args = ["analyze", "--set", "loop.rate_hz=400\nloop.spin_us=-5", "--output-dir", str(tmp_path)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "a line break in KEY=VALUE" in err
    assert list(tmp_path.iterdir()) == []  # refused before any work


@pytest.mark.parametrize("raw", ["[0, 0, 1", "{x = 1", '"socketcan:vcan0', "'a"])
def test_a_list_table_or_quoted_text_that_does_not_parse_is_named_not_taken_for_a_word(raw):
    """A missing bracket was read as the word "[0, 0, 1" and refused as "expected a list, got a string"."""
    with pytest.raises(ConfigError, match=r"--set task.path.normal=.*: not a TOML value \("):
        parse_override(f"task.path.normal={raw}")


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"recording.live_rerun": "somewhere"}, r"recording.live_rerun = 'somewhere': must be"),
        (
            {"recording.live_foxglove": "localhost"},
            r"recording.live_foxglove = 'localhost': must be HOST:PORT",
        ),
        ({"recording.live_foxglove": "127.0.0.1:99999"}, r"port in 0..65535"),
    ],
)
def test_bad_live_view_settings_are_named(overrides, message):
    with pytest.raises(ConfigError, match=message):
        load_config(overrides=overrides)


def test_good_live_view_settings_load():
    cfg = load_config(
        overrides={
            "recording.live_rerun": "rerun+http://127.0.0.1:9876/proxy",
            "recording.live_foxglove": "127.0.0.1:8765",
        }
    )
    assert cfg.recording.live_foxglove == "127.0.0.1:8765"


def test_a_configuration_with_the_old_sim_disk_section_still_loads_as_the_workpiece():
    from controller.config import config_from_dict, config_to_dict

    table = config_to_dict(load_config(overrides={"sim.workpiece.radius_m": 0.066}))
    table["sim"]["disk"] = table["sim"].pop("workpiece")
    table["sim"]["environment"] = "disk"
    cfg = config_from_dict(table)
    assert cfg.sim.workpiece.radius_m == 0.066 and cfg.sim.workpiece.shape == "disk"
    assert cfg.sim.environment == "workpiece"


def test_an_older_file_s_robot_margins_and_mass_are_cheope_s():
    """``[robot.margins]`` and ``[robot.mass]`` sat on the generic robot section until issue 29: a file
    or a recording that has them, or a --set of their old keys, lands in ``[robot.cheope.*]``."""
    from controller.config import config_from_dict

    cfg = config_from_dict(
        {"robot": {"kind": "cheope", "mass": {"platform_kg": 9.5}, "margins": {"max_condition_number": 12.0}}}
    )
    cheope = cfg.robot.model("cheope")
    assert cheope.mass.platform_kg == 9.5 and cheope.mass.slider_kg == 1.0
    assert cheope.margins.max_condition_number == 12.0
    assert (
        load_config(overrides={"robot.mass.rod_pair_kg": 0.5}).robot.model("cheope").mass.rod_pair_kg == 0.5
    )
    with pytest.raises(ConfigError, match=r"unknown key\(s\) bogus"):
        config_from_dict({"robot": {"mass": {"bogus": 1.0}}})


@pytest.mark.parametrize("dotted,old,new", CYCLE_KEYS_NOW_SECONDS)
def test_an_older_file_s_window_in_cycles_is_the_same_time_at_its_rate(dotted, old, new):
    """Each window counted in cycles until issue 37 is a time since: a file, a recording or a --set
    with the old key keeps its time at the file's own rate (a recording at 400 Hz replays bit for
    bit); a value that was never a count is named with the key that replaced it."""
    from controller.config import config_from_dict, config_to_dict

    def nested(rate_hz: float, value: object) -> dict:
        table = config_to_dict(load_config(overrides={"loop.rate_hz": rate_hz}))
        section = table
        for name in dotted.split("."):
            section = section[name]
        del section[new]
        section[old] = value
        return table

    def seconds(cfg) -> float:
        section = cfg
        for name in dotted.split("."):
            section = section.model(name) if name == "contour" else getattr(section, name)
        return getattr(section, new)

    assert seconds(config_from_dict(nested(1000.0, 10))) == pytest.approx(0.010)
    assert seconds(config_from_dict(nested(400.0, 10))) == 10 / 400.0
    assert seconds(load_config(overrides={f"{dotted}.{old}": 20})) == pytest.approx(0.05)
    for wrong in (0, 2.5, "ten", True):
        with pytest.raises(ConfigError, match=rf"{dotted}.{old} = .*the key is {dotted}.{new} now"):
            config_from_dict(nested(400.0, wrong))
    bad_rate = nested(400.0, 10)
    bad_rate["loop"]["rate_hz"] = -5
    with pytest.raises(ConfigError, match=r"loop.rate_hz = -5"):  # the rate's own error, by its own name
        config_from_dict(bad_rate)


def test_an_override_of_an_integer_too_long_to_read_names_the_key():
    from controller.config import parse_override

    with pytest.raises(ConfigError, match=r"--set loop.rate_hz: Exceeds the limit"):
        parse_override("loop.rate_hz=" + "9" * 5000)


def test_a_recording_written_under_an_older_limit_still_gives_its_law():
    """recording.buffer_bytes of 4 KiB, a robot id of 65 characters, equal limit switches: allowed
    when the file was written, refused now. Only the sections the law does not read fall back to
    their defaults; the law's own keys are checked as written."""
    from controller.config import config_to_dict, recorded_config_from_dict

    table = config_to_dict(load_config(overrides={"loop.rate_hz": 500.0}))
    table["recording"]["buffer_bytes"] = 4096
    table["monitoring"]["robot_id"] = "a" * 65
    table["sim"]["drive"]["limit_switches_m"] = [0.5, 0.5]
    cfg = recorded_config_from_dict(table)
    assert cfg.loop.rate_hz == 500.0 and cfg.recording.buffer_bytes == 4 << 20
    table["robot"]["cheope"]["joint_neutral_tcp_m"] = [0.0, float("nan"), 0.5]
    with pytest.raises(ConfigError, match=r"joint_neutral_tcp_m\[1\] = nan"):
        recorded_config_from_dict(table)


def test_a_recording_from_before_the_cells_stiffness_replays_its_guarded_speeds():
    """A 250-Hz contour session with the shipped speeds, recorded before the guarded speeds were
    checked against safety.contact.cell_stiffness_n_m: its law is rebuilt as it ran, not refused.
    One that names the key is checked as written."""
    from controller.assembly import build_law
    from controller.config import config_to_dict, recorded_config_from_dict

    table = config_to_dict(load_config(overrides={"task.kind": "contour", "loop.rate_hz": 500.0}))
    table["loop"]["rate_hz"] = 250.0  # the shipped search speed is refused at 250 Hz now
    with pytest.raises(ConfigError, match=r"search_speed_m_s = 0.01 m/s"):
        build_law(recorded_config_from_dict(table))
    del table["safety"]["contact"]["cell_stiffness_n_m"]
    build_law(recorded_config_from_dict(table))
