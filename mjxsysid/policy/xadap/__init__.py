"""The released Extreme-Adaptation ("Xadap") policy: its networks in JAX (``network``), the
import of its ONNX files (``onnx_import``) and the policy as a low-level controller
(``controller``).
"""
