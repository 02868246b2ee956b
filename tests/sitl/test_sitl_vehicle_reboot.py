"""MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN on the simulated vehicle, as the real stacks answer it.

ArduPilot (GCS_Common ``handle_preflight_reboot``): FAILED while armed, UNSUPPORTED unless
param1 is 1 (reboot) or 3 (to the bootloader); otherwise the ACK ACCEPTED goes out, the link
drops for a few seconds and the autopilot boots again: no GPS fix, no EKF origin, disarmed,
its message streams at their defaults (ArduPilot: none but HEARTBEAT until asked again),
time since boot from 0. Parameters and the stored mission persist. PX4 (Commander): param1 0
is accepted and does nothing; a reboot while armed is DENIED.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink

from sitl.vehicle.flavour import ARDUPILOT, PX4

M = mavlink
REBOOT = M.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN


def test_ardupilot_reboots_from_scratch(make_gcs):
    gcs = make_gcs(flavour=ARDUPILOT, first_fix_s=10.0, reboot_s=4.0)
    gcs.run_until(11.0)  # fixed, origin set
    assert gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 24, 1_000_000).result == 0
    gcs.send(M.MAVLink_param_set_message(1, 1, b"FENCE_ENABLE", 1.0, 9))
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    assert gcs.command(REBOOT, 1).result == M.MAV_RESULT_FAILED  # armed
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0).result == M.MAV_RESULT_ACCEPTED
    assert gcs.command(REBOOT, 2).result == M.MAV_RESULT_UNSUPPORTED
    gcs.clear()
    t_reboot = gcs.now
    assert gcs.command(REBOOT, 1).result == M.MAV_RESULT_ACCEPTED
    gcs.clear()
    gcs.run_until(t_reboot + 3.9)
    assert gcs.received == []  # the link is down
    gcs.send(M.MAVLink_param_request_read_message(1, 1, b"FENCE_ENABLE", -1))
    assert gcs.received == [] and gcs.core.counters["received_while_rebooting"] == 1
    gcs.run_until(t_reboot + 4.0 + 0.5)
    assert gcs.core.boots == 1
    assert gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 24, 1_000_000).result == 0
    gcs.run_until(t_reboot + 4.0 + 1.5)
    assert gcs.of_type("GPS_RAW_INT")[-1].fix_type < 3  # from scratch
    gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 24, -1)
    gcs.clear()
    gcs.run_until(t_reboot + 4.0 + 3.0)
    kinds = {m.get_type() for m in gcs.received}
    assert kinds == {"HEARTBEAT", "STATUSTEXT"}, kinds  # no stream it was not asked for
    assert any(t.text.startswith("PreArm") for t in gcs.of_type("STATUSTEXT"))  # no fix
    hb = gcs.of_type("HEARTBEAT")[0]
    assert not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
    assert not gcs.core.fc.has_fix  # 3 s into a boot whose EKF origin takes 10 s
    gcs.send(M.MAVLink_param_request_read_message(1, 1, b"FENCE_ENABLE", -1))
    assert gcs.of_type("PARAM_VALUE")[-1].param_value == 1.0  # parameters persist
    gcs.command(M.MAV_CMD_REQUEST_MESSAGE, 2)  # SYSTEM_TIME: time since boot from 0
    assert gcs.of_type("SYSTEM_TIME")[-1].time_boot_ms < 4_000
    gcs.clear()
    gcs.run_until(t_reboot + 4.0 + 10.5)
    assert gcs.core.fc.has_fix and gcs.of_type("GPS_GLOBAL_ORIGIN")  # the origin set again


def test_px4_accepts_a_no_op_and_denies_a_reboot_while_armed(make_gcs):
    gcs = make_gcs(flavour=PX4)
    gcs.run_until(1.0)
    assert gcs.command(REBOOT, 0).result == M.MAV_RESULT_ACCEPTED
    gcs.clear()
    gcs.run_until(2.0)
    assert gcs.of_type("HEARTBEAT")  # nothing happened
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    assert gcs.command(REBOOT, 1).result == M.MAV_RESULT_DENIED
    assert gcs.core.rebooting_until is None


def test_the_cli_reboots_ardupilot_as_fast_as_arducopter_sitl() -> None:
    """ArduCopter 4.5 SITL sent its next HEARTBEAT 2.1 s after the reboot's ACK (TCP and
    UART, measured): within a companion's 3 s heartbeat timeout, so the link never looks lost.
    ``uav-sitl vehicle`` kept the ArduPilot flavour silent 4 s, past that timeout: a companion
    tested against it always saw a lost link, never the reboot it must notice by itself."""
    from sitl.vehicle.cli import build_configs, parse_args

    (ardupilot,) = build_configs(parse_args(["--flavour", "ardupilot"]))
    assert ardupilot.reboot_s == 2.1
    (px4,) = build_configs(parse_args(["--flavour", "px4"]))
    assert px4.reboot_s == 4.0  # PX4 SITL denies the reboot: nothing measured
    (chosen,) = build_configs(parse_args(["--flavour", "ardupilot", "--reboot-s", "5"]))
    assert chosen.reboot_s == 5.0
