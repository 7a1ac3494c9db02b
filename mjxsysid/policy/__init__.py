"""The adaptive latent policy: training (:mod:`.adaptive`), the released Extreme-Adaptation policy
(:mod:`.xadap`), ONNX export (:mod:`.export`) and one interface over any frozen latent policy
(:mod:`.interface`)."""
