"""dm_control environments of the quadrotor of any θ, and the policy as a dm_env agent.

Needs the ``dmc`` extra (dm-control).

:mod:`~mjxsysid.envs.dm_quadrotor` the Physics (one vehicle of any θ, the MJX simulator's model and
rotor physics on CPU MuJoCo), the tracking tasks and :func:`make_env` / :func:`ensemble_envs`;
:mod:`~mjxsysid.envs.agents` the shipped (or any latent) policy as a dm_env agent.
"""
from mjxsysid.envs.agents import PolicyAgent
from mjxsysid.envs.dm_quadrotor import TASKS, QuadrotorPhysics, QuadrotorTask, ensemble_envs, make_env

__all__ = ["TASKS", "QuadrotorPhysics", "QuadrotorTask", "make_env", "ensemble_envs", "PolicyAgent"]
