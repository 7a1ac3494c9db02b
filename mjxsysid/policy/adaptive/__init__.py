"""mjxsysid's own adaptive policy: latent-conditioned π with privileged encoder μ and adaptation
module φ (paper §III-A).

- ``config``: EnvConfig, TrainConfig (defaults reproduce the shipped weights)
- ``networks``: μ, φ, π, V, the auxiliary decoder; observation and history layout
- ``env``: the training environment (θ resampled per episode)
- ``losses``: PPO, alignment and auxiliary losses, schedules
- ``trainer``: the jitted training iteration; ``train``: the host loop, checkpoints
- ``weights``: the ``policy.npz`` format; ``controller``: the trained policy as a low-level
  controller; ``evaluate``: its evaluation; ``focus``: weak-system files mixed into training

Inference (``controller``, ``weights``, ``networks``) imports no training module.
"""
