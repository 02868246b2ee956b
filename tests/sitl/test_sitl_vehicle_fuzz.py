"""Bad input never crashes the vehicle core and never poisons its state (hypothesis)."""

from __future__ import annotations

import math

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink

from sitl.vehicle.core import VehicleConfig, VehicleCore
from sitl.vehicle.flavour import ARDUPILOT, PX4

HANDLED = [
    mavlink.MAVLink_command_long_message, mavlink.MAVLink_command_int_message,
    mavlink.MAVLink_set_mode_message, mavlink.MAVLink_param_request_read_message,
    mavlink.MAVLink_param_set_message, mavlink.MAVLink_mission_count_message,
    mavlink.MAVLink_mission_item_int_message, mavlink.MAVLink_mission_item_message,
    mavlink.MAVLink_mission_request_int_message, mavlink.MAVLink_mission_request_message,
    mavlink.MAVLink_mission_request_list_message, mavlink.MAVLink_mission_ack_message,
    mavlink.MAVLink_mission_clear_all_message, mavlink.MAVLink_mission_set_current_message,
    mavlink.MAVLink_request_data_stream_message,
    mavlink.MAVLink_set_position_target_local_ned_message,
    mavlink.MAVLink_set_position_target_global_int_message, mavlink.MAVLink_timesync_message,
]
INT_RANGES = {
    "uint8_t": (0, 255), "int8_t": (-128, 127), "uint16_t": (0, 65535),
    "int16_t": (-32768, 32767), "uint32_t": (0, 2**32 - 1), "int32_t": (-(2**31), 2**31 - 1),
    "uint64_t": (0, 2**63), "int64_t": (-(2**63), 2**63 - 1),
}
# Fields worth aiming at the few values the vehicle reacts to.
INTERESTING = {
    "command": [16, 20, 21, 22, 176, 178, 192, 224, 300, 400, 410, 510, 511, 512, 520],
    "target_system": [0, 1], "target_component": [0, 1], "req_stream_id": [0, 2, 6, 10, 12],
    "frame": [0, 1, 3, 5, 6, 8, 9], "mission_type": [0, 1, 2, 255], "count": [0, 1, 2, 2000],
}


def _value(ftype: str, length: int, name: str) -> st.SearchStrategy:
    if ftype == "char":
        return st.text(alphabet="ABCMISNT_XYZ0", max_size=16).map(str.encode)
    if ftype in ("float", "double"):
        scalar: st.SearchStrategy = st.floats(allow_nan=True, allow_infinity=True, width=32)
    else:
        lo, hi = INT_RANGES[ftype]
        scalar = st.integers(lo, hi)
    if name in INTERESTING:
        scalar = st.sampled_from(INTERESTING[name]) | scalar
    if length:
        return st.lists(scalar, min_size=length, max_size=length)
    return scalar


@st.composite
def messages(draw: st.DrawFn):
    cls = draw(st.sampled_from(HANDLED))
    # fieldtypes follow the declaration order, array_lengths the wire order (see ``orders``).
    lengths = [cls.array_lengths[cls.orders[i]] if cls.orders else cls.array_lengths[i]
               for i in range(len(cls.fieldnames))]
    args = [draw(_value(t, n, name)) for name, t, n in zip(
        cls.fieldnames, cls.fieldtypes, lengths, strict=True)]
    return cls(*args)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(flavour=st.sampled_from([PX4, ARDUPILOT]), msgs=st.lists(messages(), min_size=1,
                                                                max_size=12),
       first_fix_s=st.sampled_from([0.0, 2.0]))
def test_random_messages_never_raise_and_state_stays_finite(flavour, msgs, first_fix_s):
    core = VehicleCore(VehicleConfig(flavour=flavour, first_fix_s=first_fix_s), now=0.0)
    codec = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    now = 0.0
    for msg in msgs:
        core.receive_datagram(msg.pack(codec), ("127.0.0.1", 1), now)
        now += 0.5
        while core.get_timer() <= now:
            core.handle_timer(core.get_timer())
        core.datagrams_to_send()
    core.handle_timer(now + 5.0)
    st_ = core.fc.state
    values = (*st_.position_ned_m, *st_.velocity_ned_m_s, st_.roll_rad, st_.pitch_rad,
              st_.yaw_rad, st_.energy_used_wh)
    assert all(math.isfinite(v) for v in values), values
    assert st_.position_ned_m[2] <= 0.0
