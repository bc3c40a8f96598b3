"""The one tolerance function every reward is built from (dm_control's `rewards.tolerance`),
and the three terms HumanoidBench's h1hand tasks share."""

from __future__ import annotations

import math

import numpy as np

_SIGMOIDS = ("gaussian", "linear", "quadratic")

# HumanoidBench's standing bar: the head (site `head`) is at least this high when standing.
STAND_HEIGHT = 1.65


def _sigmoid(
    distance: np.ndarray | float, margin: float, value_at_margin: float, sigmoid: str
) -> np.ndarray | float:
    """The sigmoid at `distance` (>= 0) from the bounds: 1 at 0, value_at_margin at margin."""
    if sigmoid == "gaussian":
        x = distance * (math.sqrt(-2.0 * math.log(value_at_margin)) / margin)
        return np.exp(-0.5 * x * x)
    if sigmoid == "linear":
        return np.maximum(0.0, 1.0 - distance * ((1.0 - value_at_margin) / margin))
    x = distance * (math.sqrt(1.0 - value_at_margin) / margin)
    return np.maximum(0.0, 1.0 - x * x)


def _check_tolerance_arguments(
    lower: float, upper: float, margin: float, sigmoid: str, value_at_margin: float
) -> None:
    if lower > upper:
        raise ValueError(f"tolerance: lower bound {lower} is above upper bound {upper}")
    if margin < 0:
        raise ValueError(f"tolerance: margin must be >= 0, got {margin}")
    if sigmoid not in _SIGMOIDS:
        raise ValueError(f"tolerance: sigmoid must be one of {_SIGMOIDS}, got {sigmoid!r}")
    if not (0.0 < value_at_margin < 1.0 or (value_at_margin == 0.0 and sigmoid != "gaussian")):
        smallest = "(0" if sigmoid == "gaussian" else "[0"
        raise ValueError(
            f"tolerance: value_at_margin must be in {smallest}, 1) for the {sigmoid} sigmoid, "
            f"got {value_at_margin}"
        )


def tolerance(
    x: np.ndarray | float,
    bounds: tuple[float, float] = (0.0, 0.0),
    margin: float = 0.0,
    sigmoid: str = "gaussian",
    value_at_margin: float = 0.1,
) -> np.ndarray | float:
    """1 where `bounds[0] <= x <= bounds[1]`; outside, a sigmoid of the distance to the nearest
    bound that falls to `value_at_margin` at distance `margin` (an indicator if margin is 0).

    Sigmoids (d = distance / margin, v = value_at_margin): gaussian exp(-0.5 (d sqrt(-2 ln v))^2),
    linear max(0, 1 - d (1 - v)), quadratic max(0, 1 - d^2 (1 - v)). x is a number (returns a
    float) or an array (returns an array of its shape).
    """
    lower, upper = bounds
    _check_tolerance_arguments(lower, upper, margin, sigmoid, value_at_margin)
    is_array = isinstance(x, np.ndarray)
    # Plain Python for numbers, few array operations for arrays: rewards call this every step.
    if not is_array:
        x = float(x)  # NumPy scalars are slower than floats in plain arithmetic
        distance = max(lower - x, x - upper, 0.0)
    elif lower == upper:
        distance = np.abs(x - lower)
    else:
        distance = np.maximum(np.maximum(lower - x, x - upper), 0.0)
    if margin == 0:
        return np.where(distance > 0.0, 0.0, 1.0) if is_array else float(distance == 0.0)
    # Every sigmoid is 1 at distance 0, so inside the bounds needs no special case.
    value = _sigmoid(distance, margin, value_at_margin, sigmoid)
    return value if is_array else float(value)


def stand(head_height: float, upright: float, height_margin: float, min_upright: float) -> float:
    """HumanoidBench's `stand(m, u0)`: head at least STAND_HEIGHT high (gaussian margin m) times
    torso upright at least u0 (linear, falling to 0 at u0 - 1.9, i.e. upside down)."""
    standing = tolerance(head_height, (STAND_HEIGHT, math.inf), margin=height_margin)
    upright_term = tolerance(
        upright, (min_upright, math.inf), margin=1.9, sigmoid="linear", value_at_margin=0.0
    )
    return standing * upright_term


def small_control(actuator_forces: np.ndarray) -> float:
    """HumanoidBench's control term: (4 + mean quadratic tolerance of the actuator forces, zero
    at |force| = 10 N) / 5, so it lies in [0.8, 1] and only ever scales the other terms."""
    per_actuator = tolerance(actuator_forces, margin=10.0, sigmoid="quadratic", value_at_margin=0.0)
    return (4.0 + float(per_actuator.sum()) / per_actuator.size) / 5.0


def dont_move(velocity_x: float, velocity_y: float) -> float:
    """Mean over x and y of a gaussian tolerance of the centre-of-mass velocity, 0.1 at 2 m/s."""
    return (tolerance(velocity_x, margin=2.0) + tolerance(velocity_y, margin=2.0)) / 2.0
