"""Flight logs of every format, read into one contract, and the physics checks a log passes before it is decoded.

:mod:`~mjxsysid.logs.formats` detects a format by content; readers: :mod:`~mjxsysid.logs.csvlog` (the CSV
contract), :mod:`~mjxsysid.logs.ulog` (PX4), :mod:`~mjxsysid.logs.crazyflie`, :mod:`~mjxsysid.logs.blackbox`,
:mod:`~mjxsysid.logs.dataflash` (ArduPilot), :mod:`~mjxsysid.logs.rosbag`, :mod:`~mjxsysid.logs.px4csv`
(data-driven-dynamics' PX4 tables); checks: :mod:`~mjxsysid.logs.checks`."""
