"""Names, types and units of ../shared/interfaces.md, in one place.

Other programs and recordings depend on these strings: change them only with a deprecation path.
"""

from __future__ import annotations

# --- PWM command (pulse width / 20 ms period) ---
PWM_STOP = 0.05  #: 1 ms pulse: motor stopped
PWM_FULL = 0.10  #: 2 ms pulse: full throttle
PWM_FRAME_HZ = 50.0  #: ESC frame rate
PWM_PERIOD_US = 20000.0  #: one 50 Hz frame in microseconds (ESC us -> PWM level)

# --- Input topics (relative names; recordings carry them with a leading slash) ---
TOPIC_PWM = "pwm"
TOPIC_BATTERY_ADC = "battery/adc"
TOPIC_TACH_ADC = "tachometer/adc"
TOPIC_THRUST_MEASURED = "thrust/measured"

# --- Output topics ---
TOPIC_BATTERY_VOLTAGE = "battery/voltage"
TOPIC_ROTOR_SPEED = "rotor/speed"
TOPIC_ROTOR_RPM = "rotor/rpm"
TOPIC_PREDICTED_SPEED = "predicted/speed"
TOPIC_PREDICTED_THRUST = "predicted/thrust"
TOPIC_DIAGNOSTICS = "diagnostics"  #: in a recording, beside the outputs (``replay`` writes it)
#: What the nodes publish diagnostics on, whatever their namespace: the absolute name the
#: diagnostic aggregator and rqt_robot_monitor listen to (status names carry the namespace).
TOPIC_DIAGNOSTICS_ABSOLUTE = "/diagnostics"

# --- Simulator ground truth (never read by train, evaluate, replay or discrepancy) ---
TOPIC_TRUTH_SPEED = "truth/speed"
TOPIC_TRUTH_THRUST = "truth/thrust"
TRUTH_PREFIX = "truth/"

# --- Message types (ROS 2 Jazzy) ---
FLOAT64 = "std_msgs/msg/Float64"
FLOAT32_ARRAY = "std_msgs/msg/Float32MultiArray"
BATTERY_STATE = "sensor_msgs/msg/BatteryState"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
JOINT_STATE = "sensor_msgs/msg/JointState"
WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"
FLOAT64_ARRAY = "std_msgs/msg/Float64MultiArray"

# --- Stamped outputs (beside the Float64 ones): header.stamp = the instant the value describes
TOPIC_ROTOR_STATE = "rotor/state"  #: JointState, velocity[0] = measured speed (rad/s)
TOPIC_PREDICTED_STATE = "predicted/state"  #: JointState, velocity[0] = predicted speed (rad/s)
#: WrenchStamped, force.z = predicted thrust (N), torque.z = reaction torque on the body (N m)
TOPIC_PREDICTED_WRENCH = "predicted/wrench"
DEFAULT_JOINT_NAME = "rotor"  #: JointState name[0] (parameter joint_name)
DEFAULT_FRAME_ID = "rotor"  #: WrenchStamped header.frame_id (parameter frame_id)
#: +1: the rotor turns counter-clockwise seen from above (parameter spin_direction), -1 clockwise
DEFAULT_SPIN_DIRECTION = 1

INPUT_TOPICS: dict[str, str] = {
    TOPIC_PWM: FLOAT64,
    TOPIC_BATTERY_ADC: FLOAT64,
    TOPIC_TACH_ADC: FLOAT32_ARRAY,
    TOPIC_THRUST_MEASURED: FLOAT64,
}
OUTPUT_TOPICS: dict[str, str] = {
    TOPIC_BATTERY_VOLTAGE: BATTERY_STATE,
    TOPIC_ROTOR_SPEED: FLOAT64,
    TOPIC_ROTOR_RPM: FLOAT64,
    TOPIC_PREDICTED_SPEED: FLOAT64,
    TOPIC_PREDICTED_THRUST: FLOAT64,
    TOPIC_ROTOR_STATE: JOINT_STATE,
    TOPIC_PREDICTED_STATE: JOINT_STATE,
    TOPIC_PREDICTED_WRENCH: WRENCH_STAMPED,
    TOPIC_DIAGNOSTICS: DIAGNOSTIC_ARRAY,
}
TRUTH_TOPICS: dict[str, str] = {TOPIC_TRUTH_SPEED: FLOAT64, TOPIC_TRUTH_THRUST: FLOAT64}

# --- The project's outputs beyond the contract (docs/ros.md): written only where they apply ---
#: one-sigma band of predicted/speed (rad/s), at its times; only for a model with a band
TOPIC_PREDICTED_SPEED_SIGMA = "predicted/speed_sigma"
#: one-sigma of predicted/thrust (N), 2 b w sigma_w; only for a model with a band and a b
TOPIC_PREDICTED_THRUST_SIGMA = "predicted/thrust_sigma"
#: the online adaptation's parameters (core/adaptation.py ``ADAPTED`` order, its ``UNITS``: the
#: propeller's loss fraction, the friction factor), one message per measured speed the estimator
#: takes; layout.dim[0].label = the names, comma-joined; only with adaptation on
TOPIC_PREDICTED_ADAPTED = "predicted/adapted"
ADDED_OUTPUT_TOPICS: dict[str, str] = {
    TOPIC_PREDICTED_SPEED_SIGMA: FLOAT64,
    TOPIC_PREDICTED_THRUST_SIGMA: FLOAT64,
    TOPIC_PREDICTED_ADAPTED: FLOAT64_ARRAY,
}

# --- Physical effects the discrepancy workflow can name (and the simulator can switch) ---
EFFECTS: tuple[str, ...] = (
    "battery_voltage",
    "rotor_lag",
    "input_delay",
    "esc_deadband",
    "spin_down_asymmetry",
    "motor_heating",
)

# --- Model inputs (the paper's three, in its order) ---
INPUT_BATTERY_VOLTAGE = "battery_voltage"
INPUT_PWM = "pwm"
INPUT_PWM_FILTERED = "pwm_filtered"
DEFAULT_INPUTS: tuple[str, ...] = (INPUT_BATTERY_VOLTAGE, INPUT_PWM, INPUT_PWM_FILTERED)
#: The physics model's predicted speed (rad/s): a physics model's output, a hybrid network's input.
INPUT_PHYSICS_SPEED = "physics_speed"
PAPER_PWM_TAU_S = 0.25  #: time constant of the paper's PWM input filter
PAPER_HIDDEN = 25

# --- The paper's battery voltage filter, eq. (1): H(z) = gain (z + 1) / (z - pole) at rate_hz ---
PAPER_FILTER_GAIN = 4.9975e-4
PAPER_FILTER_POLE = 0.9995
PAPER_FILTER_RATE_HZ = 1000.0


def paper_filter_prototype(gain: float = PAPER_FILTER_GAIN, pole: float = PAPER_FILTER_POLE,
                           rate_hz: float = PAPER_FILTER_RATE_HZ) -> tuple[float, float]:
    """(K, tau_s) of the continuous K / (tau s + 1) whose Tustin form at rate_hz is gain (z+1)/(z-pole).

    Tustin maps K/(tau s + 1) to K/(c+1) (z+1) / (z - (c-1)/(c+1)) with c = 2 tau / T, so
    c = (1 + pole) / (1 - pole) and K = gain (c + 1). The paper's numbers give K = 1.999,
    tau = 1.9995 s.
    """
    T = 1.0 / rate_hz
    c = (1.0 + pole) / (1.0 - pole)
    return gain * (c + 1.0), c * T / 2.0


#: The paper's divider ratio (battery volts per ADC volt, 1.999) and low-pass time constant
#: (1.9995 s): the battery filter's defaults, and the lag a physics model's voltage input has.
PAPER_DIVIDER_RATIO, PAPER_FILTER_TAU_S = paper_filter_prototype()

# --- Model kinds (a model file's ``kind``; ``train --kind``) ---
NETWORK = "network"  #: the paper's n-H-1 network
PHYSICS = "physics"  #: the plant's constants and effect strengths
HYBRID = "hybrid"  #: the physics speed plus a network's correction
MODEL_KINDS: tuple[str, ...] = (NETWORK, PHYSICS, HYBRID)

RAD_S_TO_RPM = 60.0 / (2.0 * 3.141592653589793)


def bare(topic: str) -> str:
    """Topic name without the leading slash, as the contract writes it."""
    return topic[1:] if topic.startswith("/") else topic
