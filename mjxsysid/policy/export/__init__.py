"""mjxsysid's trained policy as ONNX for a robot: the exported graph (``graph``) and
``mjxsysid export``, which writes and checks the files (``run``).
"""
