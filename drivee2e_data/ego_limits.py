"""The ego car's physical limits, shared by the simulator (`sim/vehicle.py`, which drives the car
in closed loop) and the labels (`sensors/ego_state.py`, which derives the logged controls with
the same numbers), so a label and the closed-loop car agree. A data-model-level module: the
training side reads labels without importing the simulator."""

WHEELBASE_SHARE = 0.6  # wheelbase of a car, as a share of its length
REAR_AXLE_SHARE = 0.3  # the rear axle sits 0.3 lengths behind the box centre
MAX_STEER_RAD = 0.6  # the front wheels' lock
FULL_THROTTLE_MPS2 = 4.0  # the acceleration at full throttle
FULL_BRAKE_MPS2 = 8.0  # the deceleration at full brake
