"""The policy on its own inputs: replayed on the logged IMU and commands, it must output the
logged motor commands."""
from __future__ import annotations

import numpy as np

from mjxsysid.logs.checks.findings import Finding

REPLAY_ROWS = 4000
"""Rows (evenly spaced) at which the policy's own action is compared with the logged one."""

REPLAY_TOLERANCE = 0.005
"""RMS difference of normalised motor commands above which the logged motor commands are not
the policy's on the logged inputs: a float32 replay of a CSV with 7 significant digits agrees
to about 1e-6, so 0.5 % of full rotor speed is far above round-off."""


def check_replay(rec, policy, zhat) -> list[Finding]:
    """The policy (a loaded latent policy with ``replay_actions``) replayed on the logged inputs
    against the logged motor commands (``zhat`` (T, 8): its replay of the log) -> a warning if
    they differ by more than :data:`REPLAY_TOLERANCE`, naming the IMU if the previous row's
    reading explains them."""
    t = len(rec["t"])
    rows = np.unique(np.linspace(1, t - 1, min(REPLAY_ROWS, t - 1)).astype(int))
    act = np.asarray(policy.replay_actions(rec["imu"], rec["a_cmd"], rec["omega_cmd"], rec["motor"], zhat, rows))
    err = float(np.sqrt(np.mean((act - np.asarray(rec["motor"])[rows]) ** 2)))
    if err <= REPLAY_TOLERANCE:
        return []
    # Rows whose IMU was read after the step: the policy acted on the previous row's reading.
    prev = np.concatenate([rec["imu"][:1], rec["imu"][:-1]])
    act1 = np.asarray(policy.replay_actions(prev, rec["a_cmd"], rec["omega_cmd"], rec["motor"], zhat, rows))
    err1 = float(np.sqrt(np.mean((act1 - np.asarray(rec["motor"])[rows]) ** 2)))
    if err1 < 0.5 * err:
        return [Finding("warning", "gyro_x … acc_z", f"each row's IMU is the reading after the motor command took "
                        f"effect: the policy outputs the logged motors from the previous row's IMU (RMS Δu {err1:.2g}, "
                        f"vs {err:.2g} from the same row): log the IMU the policy acted on (shift the IMU columns one "
                        f"row down; docs/decoding.md, 'Row timing')")]
    return [Finding("warning", "a_cmd, omega_cmd_x/y/z", f"the policy replayed on the logged IMU and commands does not "
                    f"output the logged motor commands (RMS Δu {err:.2g} of full rotor speed, tolerance "
                    f"{REPLAY_TOLERANCE}): if this log was flown by this policy, a command column (a_cmd or "
                    f"omega_cmd: e.g. another controller's rate command) or the IMU is not what the policy was "
                    f"given; log exactly the policy's inputs. A log not flown by this policy is decoded off its "
                    f"training distribution")]
