"""Kinematic multicopter model: a pure ``step(state, dt_s) -> state``.

Positions and velocities are local NED (north, east, down; metres, m/s) around home, as in
MAVLink's LOCAL_POSITION_NED. The autopilot layer sets a :class:`Setpoint`; the model moves
the vehicle towards it under velocity and acceleration limits, is pushed by wind (a drag
term the position loop must fight, which also tilts the vehicle into the wind), stays above
the ground, and drains its battery with the power it needs to fly. No clock, no randomness:
GPS noise is added where telemetry is produced (:func:`gps_reading`), with a generator
passed in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

__all__ = [
    "GRAVITY_M_S2",
    "Airframe",
    "GpsReading",
    "Setpoint",
    "VehicleState",
    "gps_reading",
    "step",
]

GRAVITY_M_S2 = 9.80665
Vec3 = tuple[float, float, float]


@dataclass(frozen=True, slots=True, kw_only=True)
class Airframe:
    """Limits and energy constants of a small quadrotor (about 1.5 kg, 4S battery)."""

    max_speed_h_m_s: float = 12.0
    max_speed_up_m_s: float = 3.0
    max_speed_down_m_s: float = 1.5
    max_accel_m_s2: float = 4.0
    max_yaw_rate_rad_s: float = math.radians(90.0)
    position_gain_1_s: float = 1.0
    velocity_gain_1_s: float = 3.0
    drag_1_s: float = 0.3
    """Linear drag of air-relative velocity (1/s): wind acceleration = drag * (wind - v)."""
    wind_compensation: float = 0.8
    """Share of the felt drag the controller cancels at once (1.0: wind only tilts it)."""
    battery_capacity_wh: float = 80.0
    hover_power_w: float = 180.0
    speed_power_w_per_m2_s2: float = 0.8
    climb_power_w_per_m_s: float = 40.0
    idle_power_w: float = 8.0
    """Power drawn armed on the ground (motors at idle)."""
    cells: int = 4

    def __post_init__(self) -> None:
        for name in ("max_speed_h_m_s", "max_speed_up_m_s", "max_speed_down_m_s",
                     "max_accel_m_s2", "battery_capacity_wh"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"Airframe.{name} must be > 0, got {getattr(self, name)}")


@dataclass(frozen=True, slots=True, kw_only=True)
class Setpoint:
    """What the autopilot asks of the model. Position wins over velocity when both are set.

    ``speed_m_s`` caps the horizontal speed (mission cruise speed); ``yaw_rad`` None keeps the
    heading, except that ``yaw_to_travel`` turns the nose into the direction of flight.
    """

    position_ned_m: Vec3 | None = None
    velocity_ned_m_s: Vec3 | None = None
    yaw_rad: float | None = None
    speed_m_s: float | None = None
    yaw_to_travel: bool = False


HOLD = Setpoint()


@dataclass(frozen=True, slots=True, kw_only=True)
class VehicleState:
    """The whole physical state; a new one is returned by every :func:`step`."""

    t_s: float = 0.0
    position_ned_m: Vec3 = (0.0, 0.0, 0.0)
    velocity_ned_m_s: Vec3 = (0.0, 0.0, 0.0)
    accel_ned_m_s2: Vec3 = (0.0, 0.0, 0.0)
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    yaw_rad: float = 0.0
    yaw_rate_rad_s: float = 0.0
    armed: bool = False
    on_ground: bool = True
    energy_used_wh: float = 0.0
    power_w: float = 0.0
    wind_ned_m_s: Vec3 = (0.0, 0.0, 0.0)
    setpoint: Setpoint = HOLD
    airframe: Airframe = field(default_factory=Airframe)

    @property
    def battery_remaining(self) -> float:
        """State of charge in [0, 1]."""
        return max(0.0, 1.0 - self.energy_used_wh / self.airframe.battery_capacity_wh)

    @property
    def battery_voltage_v(self) -> float:
        """Pack voltage: 3.5..4.2 V per cell with charge, minus a sag under load."""
        cell = 3.5 + 0.7 * self.battery_remaining - 0.0004 * self.power_w
        return self.airframe.cells * cell

    @property
    def battery_current_a(self) -> float:
        return self.power_w / max(self.battery_voltage_v, 1.0)

    @property
    def alt_m(self) -> float:
        """Height above home (m), positive up."""
        return -self.position_ned_m[2]

    @property
    def ground_speed_m_s(self) -> float:
        return math.hypot(self.velocity_ned_m_s[0], self.velocity_ned_m_s[1])


def _clamp_norm2(x: float, y: float, limit: float) -> tuple[float, float]:
    n = math.hypot(x, y)
    if n > limit > 0.0:
        return x * limit / n, y * limit / n
    return x, y


def _wrap_pi(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _desired_velocity(state: VehicleState) -> Vec3:
    sp, af = state.setpoint, state.airframe
    if sp.position_ned_m is not None:
        err = [sp.position_ned_m[i] - state.position_ned_m[i] for i in range(3)]
        dist_h = math.hypot(err[0], err[1])
        # P control, but never faster than we can stop in the remaining distance.
        v_cap_h = min(af.max_speed_h_m_s, math.sqrt(2.0 * 0.8 * af.max_accel_m_s2 * dist_h))
        if sp.speed_m_s is not None:
            v_cap_h = min(v_cap_h, sp.speed_m_s)
        vn, ve = _clamp_norm2(af.position_gain_1_s * err[0], af.position_gain_1_s * err[1],
                              v_cap_h)
        vd = af.position_gain_1_s * err[2]
    elif sp.velocity_ned_m_s is not None:
        vn, ve = sp.velocity_ned_m_s[0], sp.velocity_ned_m_s[1]
        cap = af.max_speed_h_m_s if sp.speed_m_s is None else min(sp.speed_m_s,
                                                                  af.max_speed_h_m_s)
        vn, ve = _clamp_norm2(vn, ve, cap)
        vd = sp.velocity_ned_m_s[2]
    else:
        vn = ve = vd = 0.0
    vd = min(max(vd, -af.max_speed_up_m_s), af.max_speed_down_m_s)
    return vn, ve, vd


def step(state: VehicleState, dt_s: float) -> VehicleState:
    """Advance the model by ``dt_s`` seconds (semi-implicit Euler, so keep dt <= 0.05 s)."""
    if not dt_s > 0.0:
        raise ValueError(f"dt_s must be > 0, got {dt_s}")
    af = state.airframe
    pos, vel, wind = state.position_ned_m, state.velocity_ned_m_s, state.wind_ned_m_s
    if not state.armed or (state.on_ground and _desired_velocity(state)[2] >= 0.0):
        # Disarmed or sitting on the ground without a climb command: nothing moves.
        power = af.idle_power_w if state.armed else 0.0
        return replace(
            state,
            t_s=state.t_s + dt_s,
            position_ned_m=(pos[0], pos[1], 0.0),
            velocity_ned_m_s=(0.0, 0.0, 0.0),
            accel_ned_m_s2=(0.0, 0.0, 0.0),
            roll_rad=0.0,
            pitch_rad=0.0,
            yaw_rate_rad_s=0.0,
            on_ground=True,
            power_w=power,
            energy_used_wh=state.energy_used_wh + power * dt_s / 3600.0,
        )
    v_des = _desired_velocity(state)
    # Velocity loop (command acceleration) plus the wind's drag, both bounded.
    cmd = [af.velocity_gain_1_s * (v_des[i] - vel[i]) for i in range(3)]
    drag = [af.drag_1_s * (wind[i] - vel[i]) for i in range(3)]
    # The controller compensates most of the drag it feels (like an integrator that lags),
    # within the acceleration limit: steady wind leaves a small offset, gusts push more.
    comp = af.wind_compensation
    thrust_h = _clamp_norm2(cmd[0] - comp * drag[0], cmd[1] - comp * drag[1],
                            af.max_accel_m_s2)
    thrust_d = min(max(cmd[2] - comp * drag[2], -af.max_accel_m_s2), af.max_accel_m_s2)
    acc = (thrust_h[0] + drag[0], thrust_h[1] + drag[1], thrust_d + drag[2])
    new_vel = tuple(vel[i] + acc[i] * dt_s for i in range(3))
    new_pos = [pos[i] + new_vel[i] * dt_s for i in range(3)]
    on_ground = False
    if new_pos[2] >= 0.0:  # touched the ground
        new_pos[2] = 0.0
        new_vel = (0.0, 0.0, 0.0)
        on_ground = True
    # Heading: explicit yaw, else into the direction of travel when asked and moving.
    yaw_target = state.setpoint.yaw_rad
    if yaw_target is None and state.setpoint.yaw_to_travel and math.hypot(v_des[0],
                                                                          v_des[1]) > 1.0:
        yaw_target = math.atan2(v_des[1], v_des[0])
    yaw = state.yaw_rad
    yaw_rate = 0.0
    if yaw_target is not None:
        dyaw = _wrap_pi(yaw_target - yaw)
        max_d = af.max_yaw_rate_rad_s * dt_s
        dyaw = min(max(dyaw, -max_d), max_d)
        yaw = _wrap_pi(yaw + dyaw)
        yaw_rate = dyaw / dt_s
    # Attitude from the horizontal thrust the vehicle produces (tilt into the acceleration).
    cy, sy = math.cos(yaw), math.sin(yaw)
    fwd = cy * thrust_h[0] + sy * thrust_h[1]
    right = -sy * thrust_h[0] + cy * thrust_h[1]
    pitch = -math.atan2(fwd, GRAVITY_M_S2)
    roll = math.atan2(right, GRAVITY_M_S2)
    # Power grows with airspeed (flying into the wind costs more) and with climb rate.
    speed2 = (new_vel[0] - wind[0]) ** 2 + (new_vel[1] - wind[1]) ** 2
    power = (af.hover_power_w + af.speed_power_w_per_m2_s2 * speed2
             + af.climb_power_w_per_m_s * max(0.0, -new_vel[2]))
    if on_ground:
        power = af.idle_power_w
    return replace(
        state,
        t_s=state.t_s + dt_s,
        position_ned_m=(new_pos[0], new_pos[1], new_pos[2]),
        velocity_ned_m_s=(new_vel[0], new_vel[1], new_vel[2]),
        accel_ned_m_s2=acc,
        roll_rad=roll,
        pitch_rad=pitch,
        yaw_rad=yaw,
        yaw_rate_rad_s=yaw_rate,
        on_ground=on_ground,
        power_w=power,
        energy_used_wh=state.energy_used_wh + power * dt_s / 3600.0,
    )


@dataclass(frozen=True, slots=True, kw_only=True)
class GpsReading:
    """A noisy fix in local NED metres, as a GPS receiver would report it."""

    position_ned_m: Vec3
    velocity_ned_m_s: Vec3
    eph_m: float
    epv_m: float
    satellites: int


def gps_reading(
    state: VehicleState, rng: np.random.Generator, *, sigma_h_m: float = 0.3,
    sigma_v_m: float = 0.5, sigma_vel_m_s: float = 0.05,
) -> GpsReading:
    """The true state plus white Gaussian noise with the given standard deviations."""
    n = rng.normal(0.0, 1.0, 6)
    p = state.position_ned_m
    v = state.velocity_ned_m_s
    return GpsReading(
        position_ned_m=(p[0] + sigma_h_m * n[0], p[1] + sigma_h_m * n[1],
                        p[2] + sigma_v_m * n[2]),
        velocity_ned_m_s=(v[0] + sigma_vel_m_s * n[3], v[1] + sigma_vel_m_s * n[4],
                          v[2] + sigma_vel_m_s * n[5]),
        eph_m=max(0.5, 2.0 * sigma_h_m),
        epv_m=max(0.8, 2.0 * sigma_v_m),
        satellites=14,
    )
