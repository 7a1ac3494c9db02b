"""Batched, verified MJX quadrotor simulator (DESIGN §3)."""
from mjxsysid.sim.quadrotor import (Frame, Quadrotor, SimConfig, SimState, hover_rotor_speed,
                                    quat_to_mat)
from mjxsysid.sim.rollout import closed_loop, init_batch, rollout, rollout_batch

__all__ = ["Frame", "Quadrotor", "SimConfig", "SimState", "closed_loop", "hover_rotor_speed",
           "init_batch", "quat_to_mat", "rollout", "rollout_batch"]
