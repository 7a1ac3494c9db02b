"""The experiment runs a release makes (the tune-* stages and the studies stage): each run's
folder, experiment, seed, variant and methods."""
from __future__ import annotations

from typing import NamedTuple


class ExperimentRun(NamedTuple):
    """One run of ``mjxsysid experiment``: into ``folder``, ``experiment`` with ``seed``, its
    ``variant`` (None: the default protocol) and ``methods`` (comma-separated; None: all)."""
    folder: str
    experiment: str
    seed: int
    variant: str | None
    methods: str | None


R = ExperimentRun
TUNE_RUNS = {
    "tune_nominal": (R("tune_nominal", "tune-nominal", 0, None, None),
                     R("tune_nominal_baseline_start", "tune-nominal", 0, "baseline_start", "baseline,cfm,oracle_cem"),
                     R("tune_nominal_protect", "tune-nominal", 0, "protect", "baseline,cfm,oracle_cem")),
    "tune_slow": (R("tune_slow", "tune-slow", 0, None, None),
                  R("tune_slow_heading_cost", "tune-slow", 0, "heading_cost", None),
                  R("tune_slow_baseline_start", "tune-slow", 0, "baseline_start", "baseline,cfm,oracle_cem")),
    "tune_slow_more": (R("tune_slow_true_rotor_state", "tune-slow", 0, "true_rotor_state", "cfm,oracle_cem"),
                       R("tune_slow_steady_rotor_state", "tune-slow", 0, "steady_rotor_state", "cfm,oracle_cem"),
                       R("tune_slow_seed7", "tune-slow", 7, None, None),
                       R("tune_slow_seed7_baseline_start", "tune-slow", 7, "baseline_start", "baseline,cfm,oracle_cem")),
    "tune_lemniscate": (R("tune_lemniscate", "tune-lemniscate", 0, None, None),
                        R("tune_lemniscate_no_lead_in", "tune-lemniscate", 0, "no_lead_in", None),
                        R("tune_lemniscate_no_lead_in_baseline_start", "tune-lemniscate", 0,
                          "no_lead_in,baseline_start", None)),
}
"""Per tune stage, its runs: those of docs/fair_comparisons.md §7."""
STUDY_RUNS = (R("robustness", "robustness", 0, None, None),
              R("robustness_single_latent", "robustness", 0, "single_latent", None),
              R("replay", "replay", 0, None, None),
              R("payload", "payload", 0, None, None))
"""The studies stage's runs: robustness (and its single-latent variant), replay and payload."""
del R
