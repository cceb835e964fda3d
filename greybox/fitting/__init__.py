"""Fitting grey-box parameters to flight logs by multiple shooting.

* :func:`fit` (:mod:`greybox.fitting.api`) — the entry point, returning a :class:`FitResult`
  (a :class:`~greybox.FittedModel`: predict, simulate, linearize, save);
* :class:`Solver`, :class:`GaussNewton` (:mod:`greybox.fitting.gauss_newton`) — the solver
  seam and the default structure-exploiting Gauss–Newton; :class:`FitSession` is the problem
  as solvers see it;
* :class:`Certificate` (:mod:`greybox.fitting.certificate`) — whether the end point is the
  optimum and the model adequate;
* :mod:`greybox.fitting.input_errors` — white noise on the logged inputs: the process noise
  it gives the states (a soft fit's floor), and :func:`denoise_inputs`, the logged speeds with
  the noise the vehicle does not follow taken out (what ``greybox fit`` and ``diagnose`` fit);
* :class:`GreyBoxEstimator` (:mod:`greybox.fitting.estimator`) — scikit-learn's contract;
* :func:`fit_imu` (:mod:`greybox.fitting.imu`) — what a log of the IMU and the rotor commands
  alone identifies (no position, no attitude): thrust, yaw torque, motor lag, torque gains.

The problem itself (interval functions, data layout, initial states, noise) is
:mod:`greybox.shooting`.
"""
from ..shooting import (DEFAULT_INTERVAL_S, NOISE_FLOOR, default_interval, estimate_noise, initial_node_states,
                        sensor_noise)
from .api import (IF_NEEDED, MAX_RESTARTS, THRUST_ADVICE, THRUST_IMPOSSIBLE, TRUST_REGION, FitResult, fit,
                  filtered_attitude_notes, manoeuvre_advice, per_flight_positions, progress_callback, progress_printer, thrust_ratio)
from .certificate import Certificate
from .estimator import GreyBoxEstimator
from .gauss_newton import STOPPED, FitSession, GaussNewton, Solver, budget_spent
from .imu import ImuFit, fit_imu, is_imu_only
from .input_errors import InputDenoising, denoise_inputs

__all__ = ["fit", "FitResult", "Certificate", "GreyBoxEstimator", "Solver", "GaussNewton", "FitSession",
           "estimate_noise", "sensor_noise", "NOISE_FLOOR", "initial_node_states", "DEFAULT_INTERVAL_S",
           "default_interval", "THRUST_ADVICE", "manoeuvre_advice", "MAX_RESTARTS", "TRUST_REGION", "progress_printer",
           "progress_callback", "per_flight_positions", "fit_imu", "ImuFit", "is_imu_only", "IF_NEEDED", "STOPPED",
           "budget_spent", "denoise_inputs", "InputDenoising", "thrust_ratio", "THRUST_IMPOSSIBLE",
           "filtered_attitude_notes"]
