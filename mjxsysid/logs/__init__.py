"""Flight logs: reading them (:mod:`~mjxsysid.logs.csvlog` the CSV format, :mod:`~mjxsysid.logs.ulog` PX4
ULog) and checking their physics before anything is decoded (:mod:`~mjxsysid.logs.checks`)."""
