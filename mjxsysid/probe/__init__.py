"""Probing: a latent-space search for the systems the policy flies badly (the paper's closing proposal).

:mod:`~mjxsysid.probe.search` a gradient-free search of latent space (perturbations and stretches
of the latents of prior vehicles); :mod:`~mjxsysid.probe.closed_loop` its score — decode a latent
into physical systems and fly them with the policy and the oracle — and :func:`run_probe`, which
writes the weak systems (``weak.npz``, the input of ``mjxsysid train-policy --focus``) and a report.
"""
from mjxsysid.probe.closed_loop import ProbeConfig, closed_loop_badness, make_fly, run_probe, system_badness
from mjxsysid.probe.search import SearchConfig, latent_search

__all__ = ["SearchConfig", "latent_search", "ProbeConfig", "closed_loop_badness", "make_fly", "run_probe",
           "system_badness"]
