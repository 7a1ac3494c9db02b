"""Latent collection: flights of prior vehicles with a frozen policy → (θ, ẑ) pairs and latent
trajectories, the training data of the decoders (:mod:`~mjxsysid.dataset.collect`)."""
