"""One simulated vehicle: JSBSim physics + PX4-like autopilot + sensors.

Implements :class:`flightsim.api.VehicleModel`. Each ``step`` advances one
physics step (``dt_s``, 200 Hz by default); the outer loops run every
``control_divider``-th step (``CONTROL_RATE_HZ`` = 50 Hz), like PX4's position controller:

- every step: attitude + rate control on the true attitude and body rates (an
  AHRS this good is assumed), mixer, JSBSim, collision check, sensor sampling;
- every control tick: state estimate update, commander/navigator, position and
  velocity control on the ESTIMATE (so estimate errors move the vehicle, as on
  a real one), battery.

After a crash the vehicle is frozen where it hit: motors off, disarmed, zero
velocity, ``crashed`` true.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import replace

from flightsim.api import (
    ExternalPosition,
    ExternalRange,
    FlightMode,
    GpsFix,
    Health,
    LandedState,
    NavItem,
    OffboardSetpoint,
    Outcome,
    Param,
    RangeReading,
    State,
)
from flightsim.battery import Battery
from flightsim.commander import WARNING, Commander, Motors
from flightsim.control import AttitudeController, Limits, PositionController, RateController, XQuadMixer
from flightsim.control.position import AttitudeTarget, PositionGains
from flightsim.external import ExternalFusion
from flightsim.noise import stream
from flightsim.params import Params
from flightsim.physics import F450Physics
from flightsim.sensors import GpsModel, PeerRangeModel, PositionError, RangefinderModel, StateEstimator, UwbModel
from flightsim.world import GROUND, NEAR_GROUND_M, World
from secuav_common.scenario import Scenario
from secuav_common.scenario import Vehicle as VehicleConfig

CONTROL_RATE_HZ = 50.0
_CLOCK_TOLERANCE_S = 1e-9  # as the sensors' own clocks
QUEUE_MAX = 8192  # unread readings beyond this are dropped oldest-first (headless runs may never read)


class Vehicle:
    """One scenario vehicle (a :class:`flightsim.api.VehicleModel`); built and stepped by the Simulation."""

    def __init__(self, config: VehicleConfig, scenario: Scenario, world: World, seed: int, dt_s: float) -> None:
        self.config = config
        self.sysid = config.sysid
        self.home = scenario.world.home
        self.dt_s = dt_s
        self.control_divider = max(1, round(1.0 / (CONTROL_RATE_HZ * dt_s)))
        self.world = world
        self.param_table = Params(config.sysid)
        start = config.start
        self.physics = F450Physics(self.home, start.pos_ned_m, math.radians(start.yaw_deg), dt_s)
        self.commander = Commander(self.param_table)
        self.pos_ctrl = PositionController(self.physics.mass_kg)
        self.att_ctrl = AttitudeController()
        self.rate_ctrl = RateController(self.physics.inertia_kgm2)
        self.mixer = XQuadMixer()
        self._battery = Battery(int(self.param_table["BAT1_N_CELLS"]), self.param_table["BAT1_CAPACITY"])

        sensors = config.sensors
        sid = config.sysid
        pos_err = PositionError(sensors.gps, stream(seed, sid, "position-error"))
        self.estimator = StateEstimator(pos_err, stream(seed, sid, "estimate"))
        self.gps = GpsModel(sensors.gps, self.home, pos_err, stream(seed, sid, "gps"))
        self.rangefinders = [
            RangefinderModel(r, world, stream(seed, sid, f"rangefinder{r.id}")) for r in sensors.rangefinders
        ]
        self.uwb = (
            UwbModel(sensors.uwb, scenario.anchor_positions(sensors.uwb.anchors), stream(seed, sid, "uwb"))
            if sensors.uwb is not None
            else None
        )
        self.peer_ranging = (
            PeerRangeModel(sensors.inter_vehicle, stream(seed, sid, "peers")) if sensors.inter_vehicle else None
        )

        ext = config.external
        self.external = (
            ExternalFusion(ext, sid, {p.name: p for p in (*world.walls, GROUND)}, scenario.anchor_positions())
            if ext is not None
            else None
        )

        self._sensor_models: list[RangefinderModel | UwbModel | PeerRangeModel | GpsModel] = [
            *self.rangefinders,
            *([self.uwb] if self.uwb else []),
            *([self.peer_ranging] if self.peer_ranging else []),
            self.gps,
        ]
        self._next_sample_t_s = 0.0
        self.t_s = 0.0
        self._step_count = 0
        self._motors = Motors.OFF
        self._att_target: AttitudeTarget | None = None
        self._readings: deque[RangeReading] = deque(maxlen=QUEUE_MAX)
        self._gps: deque[GpsFix] = deque(maxlen=QUEUE_MAX)
        self._frozen: State | None = None
        self._estimate = self.estimator.update(self.physics.state, 0.0)
        self.commander.observe(0.0, self._estimate)
        self._battery_warned = False
        self._apply_params()

    # -- VehicleModel: state ---------------------------------------------------------
    @property
    def truth(self) -> State:
        if self._frozen is not None:
            return replace(self._frozen, t_s=self.t_s)
        return self.physics.state

    @property
    def estimate(self) -> State:
        return self._estimate

    @property
    def armed(self) -> bool:
        return self.commander.armed

    @property
    def mode(self) -> FlightMode:
        return self.commander.mode

    @property
    def landed_state(self) -> LandedState:
        return self.commander.landed_state

    @property
    def crashed(self) -> bool:
        return self.commander.crashed

    @property
    def health(self) -> Health:
        failures = []
        if self.crashed:
            failures.append("crashed")
        if self.commander.battery_low:
            failures.append("low battery")
        return Health(gps=self.config.sensors.gps.enabled, prearm_ok=not failures, failures=failures)

    @property
    def battery(self) -> tuple[float, float]:
        return self._battery.voltage_v, self._battery.remaining

    @property
    def mission_current(self) -> int:
        return self.commander.nav.mission_current

    @property
    def mission_finished(self) -> bool:
        return self.commander.nav.mission_finished

    # -- VehicleModel: commands ----------------------------------------------------------
    def arm(self) -> Outcome:
        return self.commander.arm()

    def disarm(self, force: bool = False) -> Outcome:
        return self.commander.disarm(force)

    def takeoff(self, altitude_m: float | None = None) -> Outcome:
        return self.commander.takeoff(altitude_m)

    def land(self) -> Outcome:
        return self.commander.land()

    def return_to_launch(self) -> Outcome:
        return self.commander.return_to_launch()

    def set_mode(self, mode: FlightMode) -> Outcome:
        return self.commander.set_mode(mode)

    def reposition(self, pos_ned_m: tuple[float, float, float], yaw_rad: float | None = None) -> Outcome:
        """Fly to ``pos_ned_m`` (NaN axes: keep) and hold there in Hold mode (MAVSDK ``goto_location``)."""
        return self.commander.reposition(pos_ned_m, yaw_rad)

    def set_cruise_speed(self, speed_m_s: float | None) -> Outcome:
        """Horizontal speed of mission legs and repositions (MAV_CMD_DO_CHANGE_SPEED); None: MPC_XY_CRUISE."""
        return self.commander.set_cruise_speed(speed_m_s)

    def offboard_setpoint(self, setpoint: OffboardSetpoint) -> None:
        self.commander.offboard_setpoint(setpoint)

    def set_mission(self, items: list[NavItem]) -> Outcome:
        return self.commander.set_mission(items)

    def set_mission_current(self, seq: int) -> Outcome:
        return self.commander.set_mission_current(seq)

    def params(self) -> list[Param]:
        return self.param_table.all()

    def get_param(self, name: str) -> Param | None:
        return self.param_table.get(name)

    def set_param(self, name: str, value: float) -> Param | None:
        """Set a PX4 parameter; None when the name is unknown or the value invalid (nothing changes)."""
        result = self.param_table.set(name, value)
        if result is not None:
            self._apply_params()
        return result

    # -- ExternalInput: a companion's readings over MAVLink (scenario ``external``) ---------------
    def external_range(self, reading: ExternalRange) -> bool:
        return self.external is not None and self.external.take_range(reading, self.t_s)

    def external_position(self, fix: ExternalPosition) -> bool:
        return self.external is not None and self.external.take_position(fix, self.t_s)

    def pop_readings(self) -> list[RangeReading]:
        out = list(self._readings)
        self._readings.clear()
        return out

    def pop_gps(self) -> list[GpsFix]:
        out = list(self._gps)
        self._gps.clear()
        return out

    def pop_status_texts(self) -> list[tuple[int, str]]:
        out = self.commander.status
        self.commander.status = []
        return out

    # -- simulation ---------------------------------------------------------------------
    def step(self, peers: Mapping[int, State]) -> None:
        """Advance one physics step; ``peers`` are the other vehicles' true states (for ranging)."""
        dt = self.dt_s
        if self._step_count % self.control_divider == 0:
            self._control_tick(dt * self.control_divider)
        self._step_count += 1
        if self._frozen is None:
            self.physics.set_motors(self._inner_loop())
            truth = self.physics.step()
            self.t_s = self.physics.t_s
            pos, q = truth.pos_ned_m, truth.quat
            on_ground = pos[2] > -NEAR_GROUND_M and self.physics.on_ground
            cos_tilt = 1 - 2 * (q[1] * q[1] + q[2] * q[2])
            hit = self.world.check_collision(pos, truth.vel_ned_m_s, cos_tilt, on_ground)
            if hit is not None:
                self.crash(hit.text)
        else:
            self.t_s = self._step_count * dt
        self._sample_sensors(self.truth, peers)

    def crash(self, text: str) -> None:
        """End the flight where the vehicle is: motors off, disarmed, frozen, ``text`` as a CRITICAL status."""
        if self._frozen is not None:
            return
        self.commander.crash(text)
        self._motors = Motors.OFF
        self.physics.set_motors((0.0, 0.0, 0.0, 0.0))
        zero = (0.0, 0.0, 0.0)
        self._frozen = replace(self.physics.state, vel_ned_m_s=zero, acc_ned_m_s2=zero, rates_rad_s=zero)

    def _inner_loop(self) -> tuple[float, float, float, float]:
        if self._motors is Motors.OFF:
            return 0.0, 0.0, 0.0, 0.0
        if self._motors is Motors.IDLE or self._att_target is None:
            c = self.mixer.motor.idle_cmd
            return c, c, c, c
        truth = self.physics.state
        tgt = self._att_target
        rate_sp = self.att_ctrl.update(truth.quat, tgt.quat, tgt.yaw_rate_ff_rad_s)
        torque = self.rate_ctrl.update(rate_sp, truth.rates_rad_s, self.dt_s, self.mixer.saturated)
        return self.mixer.mix(tgt.thrust_n, torque)

    def _control_tick(self, dt: float) -> None:
        truth = self.physics.state if self._frozen is None else self.truth
        est = self.estimator.update(truth, dt)
        if self.external is not None:
            est = self.external.fuse(est, dt)
            self.commander.status.extend(self.external.pop_status())
            self._readings.extend(self.external.pop_reports())  # re-reported downlink, as PX4 streams them
        self._estimate = est
        motors, guidance = self.commander.update(self.t_s, dt, est, self.physics.on_ground)
        if self.crashed:
            motors = Motors.OFF
        if motors is not Motors.FLY or guidance is None:
            self.pos_ctrl.reset()
            self.rate_ctrl.reset()
            self._att_target = None
        else:
            if self._motors is not Motors.FLY:
                self.pos_ctrl.reset()
                self.rate_ctrl.reset()
            pc = self.pos_ctrl
            pc.limits = replace(
                pc.limits,
                xy_vel_max_m_s=guidance.xy_speed_m_s,
                z_vel_max_up_m_s=guidance.up_speed_m_s,
                z_vel_max_dn_m_s=guidance.dn_speed_m_s,
            )
            self._att_target = pc.update(
                guidance.setpoint, est.pos_ned_m, est.vel_ned_m_s, est.euler_rad[2], est.quat, dt
            )
        self._motors = motors
        m = self.physics.motors
        self._battery.update((m[0] + m[1] + m[2] + m[3]) / 4, dt)
        low = self._battery.remaining < self.param_table["BAT_LOW_THR"]
        if low and not self._battery_warned:
            self.commander.status.append((WARNING, f"Low battery: {self._battery.remaining:.0%} remaining"))
            self._battery_warned = True
        self.commander.battery_low = low

    def _sample_sensors(self, truth: State, peers: Mapping[int, State]) -> None:
        # Most physics steps sample nothing: skip them with one comparison.
        if truth.t_s + _CLOCK_TOLERANCE_S < self._next_sample_t_s:
            return
        for rf in self.rangefinders:
            r = rf.sample(truth)
            if r is not None:
                self._readings.append(r)
        if self.uwb is not None:
            self._readings.extend(self.uwb.sample(truth))
        if self.peer_ranging is not None:
            self._readings.extend(self.peer_ranging.sample(truth, peers))
        fix = self.gps.sample(truth)
        if fix is not None:
            self._gps.append(fix)
        self._next_sample_t_s = min(m.next_t_s for m in self._sensor_models)

    def _apply_params(self) -> None:
        """Push the tunable params into the controllers (speed limits, tilt, gains)."""
        p = self.param_table
        self.pos_ctrl.limits = Limits(
            xy_vel_max_m_s=p["MPC_XY_VEL_MAX"],
            z_vel_max_up_m_s=p["MPC_Z_VEL_MAX_UP"],
            z_vel_max_dn_m_s=p["MPC_Z_VEL_MAX_DN"],
            acc_hor_m_s2=p["MPC_ACC_HOR"],
            tilt_max_rad=math.radians(p["MPC_TILTMAX_AIR"]),
        )
        self.pos_ctrl.gains = PositionGains(
            xy_p=p["MPC_XY_P"],
            z_p=p["MPC_Z_P"],
            xy_vel_p=p["MPC_XY_VEL_P_ACC"],
            xy_vel_i=p["MPC_XY_VEL_I_ACC"],
            xy_vel_d=p["MPC_XY_VEL_D_ACC"],
            z_vel_p=p["MPC_Z_VEL_P_ACC"],
            z_vel_i=p["MPC_Z_VEL_I_ACC"],
        )
        self.commander.p = p
