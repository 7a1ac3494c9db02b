"""Latent collection: flights of prior vehicles with a frozen policy → (θ, ẑ) pairs and latent trajectories.

The training data of the decoders (:mod:`~mjxsysid.dataset.collect`)."""
