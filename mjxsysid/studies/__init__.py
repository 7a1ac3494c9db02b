"""Uses of the decoded models, one study a module:

- :mod:`~mjxsysid.studies.decode`      fly (or read a log), decode the latent over time (a package).
- :mod:`~mjxsysid.studies.replay`      action replay: K_θ̂ of decoded θ̂ against the policy's motors.
- :mod:`~mjxsysid.studies.robustness`  envelopes of decoded ensembles under force disturbances.
- :mod:`~mjxsysid.studies.fidelity`    closed-loop fidelity of decoded ensembles.
- :mod:`~mjxsysid.studies.noise`       decoder calibration under IMU noise.
- :mod:`~mjxsysid.studies.demo`        the CPU quick start.
"""
