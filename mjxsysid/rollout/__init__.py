"""The closed loop: any low-level controller × any θ batch × any reference → flights and metrics.

- :mod:`~mjxsysid.rollout.harness`  the one vmap boundary (:func:`fly_batch`), disturbances,
                                    the per-step loop, failure and tracking metrics.
- :mod:`~mjxsysid.rollout.flight`   flights by name (oracle / nominal K_θ, or a resolved latent
                                    policy), references by name, saving flights and metrics.
"""
