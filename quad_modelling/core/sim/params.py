"""Truth-simulator parameters: every simulator-only constant (the effect names: :mod:`quad_modelling.core.effect_names`).

The simulator (:mod:`quad_modelling.core.sim.simulate`) flies a vehicle whose rigid-body,
rotor and aerodynamic constants come from its vehicle config
(``config/vehicles/<name>.yaml``) except where a config constant is physically
inconsistent; those are replaced here, each with the original value and the
reason (:attr:`SimParams.adjustments`). Everything the vehicle configs do not
describe (ESC mapping, battery, landing gear, sensors, effect strengths,
stabiliser gains, pilot script ranges) lives in this module, one value per
field, with its unit and source in the comment next to it.

The simulator flies a vehicle file's physical constants (``rotor_*``, one value per constant), never its
``greybox`` section (the linear model's effective values).

LinkQuad (see docs/simulator.md): flown as the vehicle file gives it. Its physical rotor constants are thesis
Table 3-1's made self-consistent (Table 3-1's own identified values are the file's ``greybox`` section):

* rotor thrust constant k_f: Table 3-1's a = 1.59e-7 -> 1.0e-5 N s². Table 3-1's a gives a hover
  speed :math:`\\Omega_0 = \\sqrt{m g/(4a)} = 4302` rad/s (41,000 rpm); a 1.2 kg
  quad with ~10 in propellers hovers near 5,200 rpm. a = 1.0e-5 gives
  :math:`\\Omega_0 = 542` rad/s; a 10x4.7 in propeller gives ~2.7 N at 5,000 rpm
  (APC performance data), i.e. a ≈ 1.0e-5.
* rotor torque constant k_m: d = 2.93e-9 -> 1.843e-7 N m s², keeping Table 3-1's ratio
  d/a = 0.01843 m (the only place d enters the thesis model, Eq 3-13). Check:
  :math:`d\\Omega_0^2 = 0.054` N m per rotor, shaft power :math:`d\\Omega_0^3 =
  29` W per rotor, figure of merit 0.49 against momentum theory: plausible.
* rotor speed gain k_u = -B_m/A_m with B_m: 8.49e7 -> 1.0705e7 rad/s² per s of pulse, keeping the
  thesis model's thrust gain :math:`K = 2 B_m \\sqrt{a m g/4}` (Eq 3-7, the only
  place B_m enters the thrust) unchanged. The resulting ESC speed gain
  :math:`k_u = 1.12` rad/s per µs maps the 1.0–2.0 ms pulse range to
  0–1120 rad/s, what an RC ESC does; Table 3-1's B_m would map it to 0–8,900 rad/s.
* A_m (τ_m = 1/9.56 s), m, l, inertias and I_prop are used as given.

Crazyflie 2.1: the simulator's world keeps its own rotor thrust and torque constants (:data:`CRAZYFLIE_WORLD`,
Landry 2015), as shipped before the vehicle file's one value per constant took Foerster 2015's: fitting a model to
data made with the model's own starting constants would prove little (:attr:`SimParams.adjustments` names each).
What the file gives as measured -- mass, geometry, inertias and the rotor speed map -- the world shares, as the
LinkQuad's does: identify holds those (:data:`~quad_modelling.core.vehicle.HELD_BY_IDENTIFY` for the map), so a
world with another map (it had k_u 0.038 and Ω_off 0 against the file's 0.0408 and 381 rad/s until session 34)
left the identified physics model 1.6x the truth's angular-velocity SimErr on effect-free flights, where it is
1.03x with the world's map. Its stabiliser feeds the height references forward (``ControlParams.height_feedforward``)
and flies its low passes along cosine ramps: with the thesis's plain PID, as the LinkQuad's, the loop's integral
undershoots a low pass by about a quarter of its depth (:mod:`~quad_modelling.core.sim.control`), and the
Crazyflie's 4-12 cm passes touched down on 3 of 3 seeds and sat on their feet, which no model here predicts (the
physics model with the true constants scored 1.48x the truth's angular-velocity SimErr over every start, 1.00x over
the airborne ones).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from quad_modelling.core.vehicle import MOVED_TO_GREYBOX, RENAMED_KEYS, Motor, VehicleConfig, load_vehicle
from quad_modelling.errors import ConfigError, DataError

SIMULATED_VEHICLES = ("linkquad", "crazyflie21")

ISA_SEA_LEVEL_AIR_DENSITY = 1.225
"""Air density [kg/m³] of the ICAO standard atmosphere at sea level (ISO 2533:1975), both vehicles' flights."""


@dataclass(frozen=True)
class EscParams:
    """Speed controller: steady rotor speed :math:`\\Omega_{ss} = k_u (u - u_0) V/V_{ref}`."""

    zero_speed_input: float  # u_0 [input unit]: where the speed map reaches 0 (below the input range: its rotor stops at the range's minimum, QuadDynamics.stop_input)
    speed_gain: float  # k_u = -B_m / A_m [rad/s per input unit]
    idle_speed_fraction: float  # armed idle rotor speed / hover speed [1]

    @property
    def speed_offset(self) -> float:
        """Ω_off = -k_u u_0 [rad/s]: the map in the physics' form Ω_ss = max(k_u u + Ω_off, 0)
        (:func:`~quad_modelling.core.physics.rotors.steady_rotor_speed`) at the reference voltage."""
        return -self.speed_gain * self.zero_speed_input


@dataclass(frozen=True)
class GeometryParams:
    """Rotor and landing-gear geometry in body FRD [m]."""

    rotor_radius: float  # R [m]
    rotor_plane_z: float  # z of the rotor hubs relative to the CG, FRD (negative = above) [m]
    feet: tuple[tuple[float, float, float], ...]  # landing-gear contact points (x, y, z) FRD [m]


@dataclass(frozen=True)
class GroundParams:
    """Penalty contact at the feet: spring-damper normal force, regularised Coulomb friction."""

    natural_frequency: float  # vertical natural frequency on the ground [Hz]
    damping_ratio: float  # [1]
    friction: float  # Coulomb coefficient mu [1]
    slip_speed: float  # regularisation speed of the friction law [m/s]


@dataclass(frozen=True)
class BatteryParams:
    """LiPo pack: OCV(SoC) per cell, internal resistance, shaft power / efficiency drain."""

    cells: int  # cells in series [1]
    capacity_ah: float  # [A h]
    internal_resistance: float  # pack [ohm]
    efficiency: float  # motor + ESC, electrical to shaft power [1]
    avionics_current: float  # [A]
    initial_soc: float  # state of charge at take-off [1]
    reference_voltage: float  # V_ref: pack voltage at which the ESC gain k_u applies [V]; battery off -> V = V_ref
    voltage_noise: float  # ADC noise of the logged voltage, 1 sigma [V]


OCV_SOC = (0.0, 0.05, 0.10, 0.20, 0.30, 0.40, 0.50, 0.60, 0.70, 0.80, 0.90, 1.00)
OCV_CELL = (3.27, 3.61, 3.69, 3.71, 3.73, 3.75, 3.79, 3.83, 3.87, 3.92, 4.03, 4.20)
"""Open-circuit voltage of one LiPo cell [V] vs state of charge (typical LiPo discharge
curve at low rate, e.g. Chen & Rincón-Mora, IEEE TEC 2006, Fig 6; hobby LiPo charts)."""


@dataclass(frozen=True)
class RotorDragParams:
    """Rotor (induced/flapping) drag per rotor: :math:`F_i = -\\Omega_i K v_{air,B}`, K = diag(k_h, k_h, k_v)."""

    horizontal: float  # k_h [N s/(m rad)]
    vertical: float  # k_v [N s/(m rad)]


@dataclass(frozen=True)
class WindParams:
    """Steady wind plus first-order Gauss-Markov gusts per axis; airframe drag in moving air."""

    mean_ned: tuple[float, float, float]  # [m/s]
    gust_sigma: tuple[float, float, float]  # [m/s]
    gust_time_constant: float  # [s]
    air_density: float  # rho [kg/m³]
    body_drag_area: float  # C_D A [m²]


@dataclass(frozen=True)
class ImbalanceParams:
    """Per-motor speed-gain spread and centre-of-gravity offset."""

    motor_gains: tuple[float, float, float, float]  # multiply each ESC's k_u [1]
    cg_offset: tuple[float, float]  # CG (x, y) relative to the geometric centre, FRD [m]


@dataclass(frozen=True)
class ComOffsetParams:
    """``com_offset`` disturbance: the centre of mass sits :math:`d_z` below the IMU, which is at the
    frame's geometric centre (where every other geometry value puts the CG): the IMU is at
    :math:`r = (0, 0, -d_z)` from the CoM and the rotor hubs and feet are :math:`d_z` further up."""

    depth: float  # d_z: CoM below the IMU / geometric centre, along FRD +z [m]


@dataclass(frozen=True)
class BentArmParams:
    """``bent_arm`` disturbance: the thrust axis of motor 1 (the vehicle config's first motor) tilted by γ
    about its arm (the line from the geometric centre to the motor), towards :math:`t = e_z \\times a`
    (a = arm direction), so a positive γ gives a positive (FRD: clockwise seen from above) yaw torque
    :math:`T_1 \\sin\\gamma\\, l_1`."""

    tilt: float  # γ [rad]


@dataclass(frozen=True)
class SensorParams:
    """Motion capture and IMU noise models (1 sigma)."""

    mocap_rate: float  # [Hz]
    mocap_position_noise: float  # [m]
    mocap_attitude_noise: float  # [rad]
    mocap_velocity_window: int  # Savitzky-Golay derivative window [samples at mocap_rate]
    acc_noise: float  # white, per log sample [m/s²]
    acc_bias: float  # turn-on bias [m/s²]
    acc_drift: float  # bias random walk [m/s² / sqrt(s)]
    gyro_noise: float  # white, per log sample [rad/s]
    gyro_bias: float  # turn-on bias [rad/s]
    gyro_drift: float  # bias random walk [rad/s / sqrt(s)]


@dataclass(frozen=True)
class ControlParams:
    """Per-channel PID stabiliser (thesis Fig 1.10) and the pilot's position hold."""

    rate: float  # stabiliser rate [Hz]
    attitude_bandwidth: float  # roll/pitch closed-loop natural frequency [rad/s]
    yaw_bandwidth: float  # [rad/s]
    altitude_bandwidth: float  # [rad/s]
    damping: float  # damping ratio of every loop [1]
    integral_fraction: float  # integral gain = fraction * bandwidth * proportional gain [1]
    position_bandwidth: float  # pilot's horizontal position hold [rad/s]
    max_tilt: float  # reference roll/pitch limit [rad]
    height_feedforward: bool = False  # feed the smooth height references' rate and acceleration forward (control.py)


@dataclass(frozen=True)
class PilotParams:
    """Ranges of the seeded manoeuvre script."""

    hover_height: float  # CG height above ground while hovering [m]
    climb_time: float  # [s]
    descent_time: float  # [s]
    tilt_step: tuple[float, float]  # roll/pitch step/doublet amplitude range [rad]
    tilt_sweep: tuple[float, float]  # roll/pitch sweep amplitude range [rad]
    yaw_step: tuple[float, float]  # [rad]
    yaw_sweep: tuple[float, float]  # [rad]
    height_step: tuple[float, float]  # altitude step amplitude range [m]
    low_hover: tuple[float, float]  # CG height range of low passes (ground effect) [m]
    turn_rate: tuple[float, float]  # yaw rate range of turns (yaw with roll/pitch doublets) [rad/s]
    stick_noise: tuple[float, float, float]  # roll/pitch [rad], yaw [rad], height [m] pilot jitter, 1 sigma
    leading: tuple[str, ...] = ()  # manoeuvre classes flown first, in this order, before the random card rounds


@dataclass(frozen=True)
class SimParams:
    """Everything the truth simulator needs for one vehicle (see module docstring)."""

    vehicle: VehicleConfig  # truth constants (config values with the adjustments applied)
    adjustments: dict  # constant -> {"config": value, "used": value, "reason": text}
    esc: EscParams
    geometry: GeometryParams
    ground: GroundParams
    battery: BatteryParams
    rotor_drag: RotorDragParams
    wind: WindParams
    input_delay: float  # transport delay stabiliser -> rotor [s]
    ground_effect_min_height: float  # Cheeseman-Bennett clamp h >= c R [in rotor radii]
    imbalance: ImbalanceParams
    com_offset: ComOffsetParams
    bent_arm: BentArmParams
    sensors: SensorParams
    control: ControlParams
    pilot: PilotParams
    physics_rate: float = 1000.0  # RK4 rate [Hz]
    log_rate: float = 100.0  # [Hz]

    @property
    def motor_time_constant(self) -> float:
        """tau_m [s]: the rotor time constant (thesis Eq A-0-1: -1/A_m)."""
        return self.vehicle.value("rotor_time_constant")

    @property
    def rest_height(self) -> float:
        """CG height above ground when standing on the feet [m] (undamaged airframe: with ``com_offset`` the
        CoM sits d_z lower, :attr:`QuadDynamics.rest_height <quad_modelling.core.sim.dynamics.QuadDynamics.rest_height>`)."""
        return max(f[2] for f in self.geometry.feet)

    def replace(self, **changes) -> SimParams:
        """A copy with some fields replaced (e.g. ``params.replace(input_delay=0.03)``)."""
        return dataclasses.replace(self, **changes)

    def truth_model_notes(self) -> dict:
        """JSON-ready: what the truth model (:mod:`quad_modelling.core.sim.truth_model`) needs to rebuild this
        simulator's dynamics and command path from a log (the log's ``notes[TRUTH_NOTES_KEY]``), read back by
        :func:`sim_params_from_notes`. The stabiliser, pilot and sensor parameters are not part of it (the truth
        model is fed the logged commands and anchored on the logged measurements)."""
        vehicle = self.vehicle
        return {
            "vehicle": vehicle.name,
            "constants": {key: c.value for key, c in vehicle.constants.items()},
            "motors": [{"name": m.name, "position": list(m.position), "yaw_sign": m.yaw_sign} for m in vehicle.motors],
            "input_min": vehicle.input_min,
            "input_max": vehicle.input_max,
            **{name: _plain(dataclasses.asdict(getattr(self, name))) for name in _TRUTH_SECTIONS},
            "input_delay": self.input_delay,
            "ground_effect_min_height": self.ground_effect_min_height,
            "physics_rate": self.physics_rate,
            "log_rate": self.log_rate,
            "control_rate": self.control.rate,
        }

    def effect_parameters(self, effects: tuple[str, ...]) -> dict:
        """JSON-ready parameters of the given effects (what a diagnosis should find)."""
        out: dict = {}
        for name in effects:
            if name == "rotor_drag":
                out[name] = {"k_h_N_s_per_m_rad": self.rotor_drag.horizontal, "k_v_N_s_per_m_rad": self.rotor_drag.vertical}
            elif name == "battery":
                out[name] = {k: _plain(v) for k, v in dataclasses.asdict(self.battery).items()}
                out[name]["ocv_soc"] = list(OCV_SOC)
                out[name]["ocv_cell_V"] = list(OCV_CELL)
            elif name == "motor_lag":
                out[name] = {"time_constant_s": self.motor_time_constant}
            elif name == "input_delay":
                out[name] = {"delay_s": self.input_delay}
            elif name == "ground_effect":
                out[name] = {
                    "model": "Cheeseman-Bennett T/T_inf = 1/(1-(R/(4h))^2)",
                    "rotor_radius_m": self.geometry.rotor_radius,
                    "rotor_plane_z_m": self.geometry.rotor_plane_z,
                    "min_height_rotor_radii": self.ground_effect_min_height,
                }
            elif name == "gyroscopic":
                out[name] = {"prop_inertia_kg_m2": self.vehicle.value("prop_inertia"), "inertia_kg_m2": self.vehicle.inertia.tolist()}
            elif name == "motor_imbalance":
                out[name] = {"motor_gains": list(self.imbalance.motor_gains), "cg_offset_m": list(self.imbalance.cg_offset)}
            elif name == "wind":
                out[name] = {k: _plain(v) for k, v in dataclasses.asdict(self.wind).items()}
            elif name == "com_offset":
                depth = self.com_offset.depth
                out[name] = {
                    "com_below_imu_m": depth,
                    "imu_position_from_com_frd_m": [0.0, 0.0, -depth],
                    "rotor_plane_z_from_com_m": self.geometry.rotor_plane_z - depth,
                }
            elif name == "bent_arm":
                arm = float(np.hypot(*self.vehicle.motor_positions[0]))
                gamma = self.bent_arm.tilt
                out[name] = {
                    "motor": 1,
                    "tilt_rad": gamma,
                    "arm_length_m": arm,
                    "yaw_torque_per_thrust_m": float(np.sin(gamma)) * arm,  # T_1 sin(gamma) l_1 per newton of T_1
                    "side_force_per_thrust": float(np.sin(gamma)),
                    "yaw_torque_at_mg_over_4_N_m": self.vehicle.hover_thrust_per_rotor * float(np.sin(gamma)) * arm,
                }
        return out


TRUTH_NOTES_KEY = "truth_model"
"""Key of :meth:`SimParams.truth_model_notes` in a simulated log's notes."""

_TRUTH_SECTIONS = {"esc": EscParams, "geometry": GeometryParams, "ground": GroundParams, "battery": BatteryParams,
                   "rotor_drag": RotorDragParams, "wind": WindParams, "imbalance": ImbalanceParams,
                   "com_offset": ComOffsetParams, "bent_arm": BentArmParams}
"""The parameter groups of :meth:`SimParams.truth_model_notes` and their dataclasses."""


def _tuples(value):
    """JSON lists back to the tuples the frozen parameter dataclasses hold."""
    return tuple(_tuples(v) for v in value) if isinstance(value, list) else value


def sim_params_from_notes(notes: dict, where: str) -> SimParams:
    """The simulator parameters a log was flown with, from its notes (:meth:`SimParams.truth_model_notes`): the
    shipped vehicle's simulator parameters with every value the notes hold put back. DataError naming ``where``
    (the log) when the log is not simulated or was simulated before the notes held these values."""
    if not isinstance(notes, dict) or notes.get("generator") != "quad_modelling.core.sim.simulate":
        raise DataError(f"{where}: not a simulated flight (no simulator notes): the truth model predicts only logs "
                        f"written by quad-modelling simulate")
    saved = notes.get(TRUTH_NOTES_KEY)
    if not isinstance(saved, dict):
        raise DataError(f"{where}: simulated (sim_version {notes.get('sim_version')}) before the logs kept the truth "
                        f"model's parameters (notes key {TRUTH_NOTES_KEY!r}); simulate it again")
    stale = sorted(set(saved.get("constants") or {}) & (set(RENAMED_KEYS) | set(MOVED_TO_GREYBOX)))
    if stale:
        raise DataError(f"{where}: simulated (sim_version {notes.get('sim_version')}) before the vehicle files held one value "
                        f"per physical constant (notes constant {stale[0]!r}, docs/formats.md); simulate it again")
    try:
        base = sim_params_for(str(saved["vehicle"]))
        vehicle = base.vehicle.with_values({k: float(v) for k, v in saved["constants"].items()}, "simulator notes")
        motors = tuple(Motor(str(m["name"]), (float(m["position"][0]), float(m["position"][1])), int(m["yaw_sign"]))
                       for m in saved["motors"])
        vehicle = dataclasses.replace(vehicle, motors=motors, input_min=float(saved["input_min"]),
                                      input_max=float(saved["input_max"]))
        sections = {name: cls(**{k: _tuples(v) for k, v in saved[name].items()}) for name, cls in _TRUTH_SECTIONS.items()}
        return base.replace(vehicle=vehicle, **sections, input_delay=float(saved["input_delay"]),
                            ground_effect_min_height=float(saved["ground_effect_min_height"]),
                            physics_rate=float(saved["physics_rate"]), log_rate=float(saved["log_rate"]),
                            control=dataclasses.replace(base.control, rate=float(saved["control_rate"])))
    except (KeyError, TypeError, ValueError, IndexError) as err:
        raise DataError(f"{where}: simulator notes key {TRUTH_NOTES_KEY!r} is malformed ({type(err).__name__}: {err}); "
                        f"simulate the flight again") from err


def _plain(value):
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


BENT_ARM_TILT = float(np.deg2rad(3.0))
"""γ of ``bent_arm`` [rad], both vehicles (guess): a few degrees is what a hard landing leaves in an arm or
motor mount and what pilots notice as a yaw drift the trim has to hold; under ~1° the thrust tilt is lost
in the motor spread, over ~5° it is seen on the ground and straightened. Racing frames tilt motors 3-5°
on purpose for yaw authority, so 3° is also a size real airframes fly with."""


# --------------------------------------------------------------------------- LinkQuad

def _world(vehicle: VehicleConfig, world: dict[str, tuple[float, str]]) -> tuple[VehicleConfig, dict]:
    """(the simulator's vehicle, its adjustments): ``vehicle``'s physical constants with the simulator's own
    ``world`` values {key: (value, reason)} put in, without a ``greybox`` section (the simulator flies physics)."""
    adjusted = dataclasses.replace(vehicle.with_values({k: v for k, (v, _) in world.items()}, "simulator world (sim/params.py)"),
                                   greybox={})
    return adjusted, {k: {"config": vehicle.value(k), "used": v, "reason": why} for k, (v, why) in world.items()}


def _linkquad(vehicle: VehicleConfig) -> SimParams:
    adjusted, adjustments = _world(vehicle, {})
    hover = adjusted.hover_rotor_speed
    return SimParams(
        vehicle=adjusted,
        adjustments=adjustments,
        esc=EscParams(
            zero_speed_input=1.0e-3,  # s: RC ESC zero-throttle pulse (1.0 ms; ESC convention)
            speed_gain=adjusted.value("rotor_speed_gain"),  # k_u = -B_m/A_m [rad/s per s] (vehicle file, module docstring)
            idle_speed_fraction=0.25,  # guess: armed idle
        ),
        geometry=GeometryParams(
            rotor_radius=0.127,  # m: 10 in propeller (fits 0.304 m between adjacent hubs)
            rotor_plane_z=-0.04,  # m: hubs 4 cm above the CG (guess from thesis Fig 1.11)
            feet=((0.15, 0.15, 0.12), (-0.15, 0.15, 0.12), (-0.15, -0.15, 0.12), (0.15, -0.15, 0.12)),  # m: 20 cm high frame (thesis 1.4.2)
        ),
        ground=GroundParams(natural_frequency=15.0, damping_ratio=0.8, friction=0.6, slip_speed=0.02),  # guess: stiff gear, rubber feet
        battery=BatteryParams(
            cells=3,  # thesis 1.4.2: "12.5 V" pack (3 cells in series; "6-cell" read as 3S2P)
            capacity_ah=5.2,  # thesis 1.4.2: 5200 mAh
            internal_resistance=0.025,  # ohm: typical 5 Ah 3S LiPo pack
            efficiency=0.7,  # motor + ESC, typical for hobby brushless drives
            avionics_current=0.8,  # A: LinkBoard III with two Gumstix (guess)
            initial_soc=0.95,
            reference_voltage=12.0,  # V: nominal loaded pack voltage at which k_u is stated
            voltage_noise=0.01,
        ),
        rotor_drag=RotorDragParams(
            horizontal=0.3 * adjusted.mass / (4 * hover),  # drag/mass 0.3 1/s at hover (Foerster 2015 Crazyflie ratio scaled)
            vertical=1.12 * 0.3 * adjusted.mass / (4 * hover),  # k_v/k_h = 1.12 (Foerster 2015)
        ),
        wind=WindParams(
            mean_ned=(0.8, -0.5, 0.0),  # m/s: a draught from a door / ventilation (guess)
            gust_sigma=(0.4, 0.4, 0.15),  # m/s
            gust_time_constant=2.0,  # s
            air_density=ISA_SEA_LEVEL_AIR_DENSITY,
            body_drag_area=0.05,  # m²: C_D ~1 times ~0.05 m² casing (guess)
        ),
        input_delay=0.02,  # s: stabiliser -> ESC PWM update (guess, typical 50 Hz-class ESC loop)
        ground_effect_min_height=0.5,  # R: the model's singularity is at h = R/4
        imbalance=ImbalanceParams(motor_gains=(1.03, 0.98, 1.015, 0.975), cg_offset=(0.006, -0.004)),
        # guess: the 5.2 Ah 3S pack (~0.4 kg, a third of the 1.2 kg) strapped flat under the centre plate that
        # carries the IMU, its centre ~3 cm below it: 0.4/1.2 x 0.03 m = 0.01 m. Hung lower (d_z = 0.03-0.04 m)
        # it doubles the hub height above the CoM, and the hub moment of rotor drag (a velocity-to-pitch
        # coupling the 3.5 rad/s attitude loop barely holds) topples some seeded flights (docs/simulator.md)
        com_offset=ComOffsetParams(depth=0.01),
        bent_arm=BentArmParams(tilt=BENT_ARM_TILT),
        sensors=_sensors(),
        control=ControlParams(
            rate=250.0,  # Hz: thesis onboard loop (1.4.3.1)
            attitude_bandwidth=3.5,  # rad/s: with the 9.56 rad/s motor pole and 20 ms delay, closed-loop damping ~0.45
            yaw_bandwidth=2.0,
            altitude_bandwidth=1.5,
            damping=0.9,
            integral_fraction=0.15,
            position_bandwidth=0.5,
            max_tilt=np.deg2rad(15.0),
        ),
        pilot=PilotParams(
            hover_height=1.0,
            climb_time=4.0,
            descent_time=7.0,
            tilt_step=(np.deg2rad(2.0), np.deg2rad(10.0)),
            tilt_sweep=(np.deg2rad(2.0), np.deg2rad(5.0)),
            yaw_step=(np.deg2rad(15.0), np.deg2rad(60.0)),
            yaw_sweep=(np.deg2rad(5.0), np.deg2rad(15.0)),
            height_step=(0.15, 0.5),
            low_hover=(0.2, 0.45),
            turn_rate=(0.6, 1.2),  # rad/s: brisk turns the slow motors (105 ms) still stabilise with every effect on
            stick_noise=(np.deg2rad(0.4), np.deg2rad(1.0), 0.01),
        ),
    )


def _sensors(position_noise: float = 0.5e-3) -> SensorParams:
    return SensorParams(
        mocap_rate=250.0,  # Hz: Vicon MX (thesis 1.4.3.2)
        mocap_position_noise=position_noise,  # m: "millimetre accuracy"
        mocap_attitude_noise=np.deg2rad(0.05),
        mocap_velocity_window=11,  # 44 ms Savitzky-Golay derivative
        acc_noise=0.05,  # m/s² per 100 Hz sample (MEMS + airframe vibration, guess)
        acc_bias=0.05,
        acc_drift=0.002,
        gyro_noise=0.003,  # rad/s per 100 Hz sample
        gyro_bias=0.005,
        gyro_drift=0.0003,
    )


# --------------------------------------------------------------------------- Crazyflie 2.1


CRAZYFLIE_WORLD = {
    "rotor_thrust_constant": (2.88e-8, "Landry 2015 (MIT MSc): kf 3.16e-10 N/rpm^2; the vehicle file's is Foerster 2015's fit"),
    "rotor_torque_constant": (7.24e-10, "Landry 2015: km 7.94e-12 N m/rpm^2"),
}
"""The simulated Crazyflie's own rotor constants {key: (value, reason)} where they differ from the vehicle file (module
docstring): the world the simulator has flown since before the vehicle file held one value per constant."""


def _crazyflie21(vehicle: VehicleConfig) -> SimParams:
    arm = vehicle.value("arm_length")
    foot = arm / np.sqrt(2.0)
    vehicle, adjustments = _world(vehicle, CRAZYFLIE_WORLD)
    return SimParams(
        vehicle=vehicle,
        adjustments=adjustments,
        esc=EscParams(
            # u_0 = -Ω_off / k_u [PWM]: the vehicle file's measured map (Foerster 2015) in the ESC's form; negative,
            # the map's intercept is a fit over the spinning range (u = 15000..65535), not a stopped rotor
            zero_speed_input=-vehicle.value("rotor_speed_offset") / vehicle.value("rotor_speed_gain"),
            speed_gain=vehicle.value("rotor_speed_gain"),  # k_u [rad/s per count]
            idle_speed_fraction=0.3,  # armed idle 455 rad/s, above the map's 381 rad/s at PWM 0 (0.25 asked for less)
        ),
        geometry=GeometryParams(
            rotor_radius=0.0235,  # m: 47 mm propeller (Bitcraze datasheet)
            rotor_plane_z=-0.008,  # m: propellers on top of the motor pods
            feet=tuple((sx * foot, sy * foot, 0.015) for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1))),  # m: sits on motor pods
        ),
        ground=GroundParams(natural_frequency=15.0, damping_ratio=0.8, friction=0.6, slip_speed=0.02),
        battery=BatteryParams(
            cells=1,
            capacity_ah=0.25,  # Bitcraze: 250 mAh 1S LiPo
            internal_resistance=0.08,  # ohm: small 1S pack
            efficiency=0.8,  # Landry's d gives ~10 W shaft power at hover, more than the real ~8 W draw; see docs
            avionics_current=0.1,
            initial_soc=1.0,
            reference_voltage=3.8,
            voltage_noise=0.005,
        ),
        rotor_drag=RotorDragParams(horizontal=9.1785e-7, vertical=10.311e-7),  # Foerster 2015, K_aero (kg/rad)
        wind=WindParams(
            mean_ned=(0.4, -0.25, 0.0),
            gust_sigma=(0.2, 0.2, 0.08),
            gust_time_constant=2.0,
            air_density=ISA_SEA_LEVEL_AIR_DENSITY,
            body_drag_area=1.0e-3,  # m²: ~10 cm² frame + battery (guess)
        ),
        input_delay=0.008,  # s: guess (500 Hz firmware loop, PWM update)
        ground_effect_min_height=0.5,
        imbalance=ImbalanceParams(motor_gains=(1.03, 0.98, 1.015, 0.975), cg_offset=(0.0015, -0.001)),
        # guess: the 7 g pack (a quarter of the 27 g) hung on a deck ~4 cm under the PCB that carries the IMU:
        # 0.26 x 0.04 m = 0.01 m
        com_offset=ComOffsetParams(depth=0.01),
        bent_arm=BentArmParams(tilt=BENT_ARM_TILT),
        sensors=_sensors(),
        control=ControlParams(
            rate=250.0,
            attitude_bandwidth=6.0,  # rad/s: with the 20 rad/s motor pole and 8 ms delay, closed-loop damping ~0.57
            yaw_bandwidth=3.0,
            altitude_bandwidth=2.0,
            damping=0.9,
            integral_fraction=0.15,
            position_bandwidth=0.6,
            max_tilt=np.deg2rad(15.0),
            # as the firmware's position controller feeds its setpoint's velocity forward (position_controller_pid.c);
            # without it a low pass undershot by a quarter of its depth and sat on its feet (module docstring)
            height_feedforward=True,
        ),
        pilot=PilotParams(
            hover_height=0.5,
            climb_time=3.0,
            descent_time=6.0,
            tilt_step=(np.deg2rad(2.0), np.deg2rad(10.0)),
            tilt_sweep=(np.deg2rad(2.0), np.deg2rad(5.0)),
            yaw_step=(np.deg2rad(15.0), np.deg2rad(60.0)),
            yaw_sweep=(np.deg2rad(5.0), np.deg2rad(15.0)),
            height_step=(0.08, 0.2),
            # m: 3.5-7 R. Lower, a pass with the battery on touched down: the altitude integral follows the voltage
            # sag, a ramp, 1.5-3.5 cm low (session 34's review: 4 cm asked, its feet 1.5 cm below the CG)
            low_hover=(0.08, 0.16),
            turn_rate=(1.0, 2.0),  # rad/s
            stick_noise=(np.deg2rad(0.4), np.deg2rad(1.0), 0.005),
        ),
    )


_BUILDERS = {"linkquad": _linkquad, "crazyflie21": _crazyflie21}


def sim_params_for(vehicle: str | VehicleConfig) -> SimParams:
    """Simulator parameters of a shipped vehicle (``linkquad`` or ``crazyflie21``)."""
    config = vehicle if isinstance(vehicle, VehicleConfig) else load_vehicle(vehicle)
    builder = _BUILDERS.get(config.name)
    if builder is None:
        raise ConfigError(
            f"{config.path}: no simulator parameters for vehicle {config.name!r}; simulated vehicles: {', '.join(SIMULATED_VEHICLES)}"
        )
    return builder(config)


__all__ = ["SimParams", "sim_params_for"]
