"""Uses of the decoded models: action replay, robustness envelopes, closed-loop fidelity, IMU noise.

One use a module (the commands that measure them for the docs are :mod:`mjxsysid.experiments`):

- :mod:`~mjxsysid.uses.replay`      action replay: K_θ̂ of decoded θ̂ against the policy's motors.
- :mod:`~mjxsysid.uses.robustness`  envelopes of decoded ensembles under force disturbances.
- :mod:`~mjxsysid.uses.fidelity`    closed-loop fidelity of decoded ensembles.
- :mod:`~mjxsysid.uses.imu_noise`   decoder calibration under IMU noise.
"""
